/* boot2_image.S - puts boot2 with its CRC (made by `mkimage boot2`) into the image's .boot2 section. */
    .section .boot2, "ax"
    .incbin BOOT2_BIN
