"""pmctl: controller and digital twin for the 3-RPS + XY-table hybrid milling machine."""

__version__ = "0.1.0"
