$I  ; View build info
$G  ; View G-code parser state
$$  ; View current settings
?  ; View current status

M8  ; Turn on fan
G90  ; Set absolute distance mode
G21  ; Set all units in millimeters

G00 Z5.000000
G00 X274.697210 Y30.874980

M03 S700  ; Turn laser on

G02 X274.184715 Y30.541697 Z-0.125000 I-0.862823 J0.766100 F800
G03 X273.901090 Y30.441780 Z-0.125000 I1.510632 J-4.740599
G00 Z5.000000

(End cutting path id: path1492)


(Start cutting path id: path1483)
(Change tool to Default tool)

G00 Z5.000000
G00 X280.968040 Y30.519310

G01 Z-0.125000 F100.0(Penetrate)
G02 X280.817076 Y30.522882 Z-0.125000 I-0.073719 J0.076288 F800
G02 X280.794040 Y30.606310 Z-0.125000 I0.067485 J0.063528
G00 Z5.000000

(End cutting path id: path1483)


(Start cutting path id: path1481)
(Change tool to Default tool)

G00 Z5.000000
G00 X280.814640 Y30.027030

G01 Z-0.125000 F100.0(Penetrate)
G02 X280.693803 Y28.816721 Z-0.125000 I-40.260449 J3.408410 F800
G03 X280.704030 Y27.967290 Z-0.125000 I3.341902 J-0.384541
G00 Z5.000000

(End cutting path id: path1481)


(Start cutting path id: path1479)
(Change tool to Default tool)

G00 Z5.000000
G00 X282.709350 Y29.825770

G01 Z-0.125000 F100.0(Penetrate)
G03 X282.159642 Y28.708163 Z-0.125000 I0.772784 J-1.074097 F800
G03 X283.231620 Y27.634230 Z-0.125000 I1.110538 J0.036537
G03 X284.085339 Y28.985348 Z-0.125000 I-0.015886 J0.955313
G03 X283.299620 Y30.143350 Z-0.125000 I-3.785698 J-1.723083
G03 X282.697021 Y30.327570 Z-0.125000 I-0.485311 J-0.509808
G03 X282.010490 Y30.046550 Z-0.125000 I0.281815 J-1.667577
G00 Z5.000000

(End cutting path id: path1479)


(Start cutting path id: path1475)
(Change tool to Default tool)

G00 Z5.000000
G00 X279.837530 Y30.426980

G01 Z-0.125000 F100.0(Penetrate)
G03 X277.672434 Y29.754083 Z-0.125000 I-0.377360 J-2.605444 F800
G03 X277.438684 Y28.929261 Z-0.125000 I0.558586 J-0.603833
G03 X278.095330 Y28.242912 Z-0.125000 I0.969718 J0.270462
G03 X279.820030 Y28.639350 Z-0.125000 I0.533282 J1.629825
G00 Z5.000000

(End cutting path id: path1475)


(Start cutting path id: path1473)
(Change tool to Default tool)

G00 Z5.000000
G00 X275.766270 Y29.875100

G01 Z-0.125000 F100.0(Penetrate)
G02 X276.399758 Y28.964503 Z-0.125000 I0.092830 J-0.611072 F800
G03 X276.353780 Y27.927740 Z-0.125000 I1.019128 J-0.564597
G02 X276.664974 Y30.270425 Z-0.125000 I5.509992 J0.460084
G02 X277.717870 Y30.655560 Z-0.125000 I0.688022 J-0.249148
G00 Z5.000000

(End cutting path id: path1473)


(Start cutting path id: path1471)
(Change tool to Default tool)

G00 Z5.000000
G00 X273.111960 Y29.542770

G01 Z-0.125000 F100.0(Penetrate)
G03 X273.129484 Y28.019821 Z-0.125000 I0.843372 J-0.751871 F800
G03 X273.625460 Y27.825580 Z-0.125000 I0.450900 J0.420996
G03 X274.250986 Y28.070687 Z-0.125000 I0.014189 J0.884531
G03 X274.569670 Y28.544610 Z-0.125000 I-0.921296 J0.963623
G03 X274.264326 Y29.417793 Z-0.125000 I-1.132023 J0.094122
G03 X273.111960 Y29.542770 Z-0.125000 I-0.649325 J-0.611923
G01 X273.110589 Y29.547281 Z-0.125000
G02 X274.672830 Y28.706970 Z-0.125000 I0.384879 J-1.156817
G03 X275.117727 Y27.958124 Z-0.125000 I0.906960 J0.032252
G03 X275.451780 Y28.062290 Z-0.125000 I0.120008 J0.202868
G00 Z5.000000

(End cutting path id: path1471)


(Start cutting path id: path1469)
(Change tool to Default tool)

G00 Z5.000000
G00 X266.775980 Y27.435300

G01 Z-0.125000 F100.0(Penetrate)
G03 X268.344977 Y29.263416 Z-0.125000 I-5.408116 J6.228925 F800
G03 X269.517700 Y32.353090 Z-0.125000 I-7.036178 J4.438064
G02 X269.875128 Y30.645324 Z-0.125000 I-8.950005 J-2.764483
G02 X269.996440 Y29.002010 Z-0.125000 I-20.802646 J-2.361823
G03 X271.189356 Y30.190276 Z-0.125000 I-2.216286 J3.417886
G03 X272.781760 Y33.441070 Z-0.125000 I-12.277903 J8.029755
G02 X271.999449 Y28.475320 Z-0.125000 I-15.332993 J-0.128919
G03 X268.875108 Y17.942479 Z-0.125000 I160.121744 J-53.226496
G03 X267.453544 Y8.819285 Z-0.125000 I44.199343 J-11.559429
G03 X269.702350 Y6.085430 Z-0.125000 I2.616314 J-0.139716
G00 Z5.000000

(End cutting path id: path1469)


(Start cutting path id: path1463)
(Change tool to Default tool)

G00 Z5.000000
G00 X282.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X282.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1463)


(Start cutting path id: path1461)
(Change tool to Default tool)

G00 Z5.000000
G00 X281.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X281.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1461)


(Start cutting path id: path1459)
(Change tool to Default tool)

G00 Z5.000000
G00 X280.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X280.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1459)


(Start cutting path id: path1457)
(Change tool to Default tool)

G00 Z5.000000
G00 X279.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X279.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1457)


(Start cutting path id: path1455)
(Change tool to Default tool)

G00 Z5.000000
G00 X278.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X278.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1455)


(Start cutting path id: path1453)
(Change tool to Default tool)

G00 Z5.000000
G00 X277.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X277.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1453)


(Start cutting path id: path1451)
(Change tool to Default tool)

G00 Z5.000000
G00 X276.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X276.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1451)


(Start cutting path id: path1449)
(Change tool to Default tool)

G00 Z5.000000
G00 X275.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X275.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1449)


(Start cutting path id: path1447)
(Change tool to Default tool)

G00 Z5.000000
G00 X274.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X274.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1447)


(Start cutting path id: path1443)
(Change tool to Default tool)

G00 Z5.000000
G00 X272.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X272.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1443)


(Start cutting path id: path1441)
(Change tool to Default tool)

G00 Z5.000000
G00 X271.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X271.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1441)


(Start cutting path id: path1439)
(Change tool to Default tool)

G00 Z5.000000
G00 X270.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X270.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1439)


(Start cutting path id: path1437)
(Change tool to Default tool)

G00 Z5.000000
G00 X269.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X269.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1437)


(Start cutting path id: path1435)
(Change tool to Default tool)

G00 Z5.000000
G00 X268.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X268.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1435)


(Start cutting path id: path1433)
(Change tool to Default tool)

G00 Z5.000000
G00 X267.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X267.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1433)


(Start cutting path id: path1431)
(Change tool to Default tool)

G00 Z5.000000
G00 X266.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X266.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1431)


(Start cutting path id: path1429)
(Change tool to Default tool)

G00 Z5.000000
G00 X265.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X265.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1429)


(Start cutting path id: path1427)
(Change tool to Default tool)

G00 Z5.000000
G00 X264.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X264.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1427)


(Start cutting path id: path1423)
(Change tool to Default tool)

G00 Z5.000000
G00 X262.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X262.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1423)


(Start cutting path id: path1421)
(Change tool to Default tool)

G00 Z5.000000
G00 X261.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X261.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1421)


(Start cutting path id: path1419)
(Change tool to Default tool)

G00 Z5.000000
G00 X260.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X260.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1419)


(Start cutting path id: path1417)
(Change tool to Default tool)

G00 Z5.000000
G00 X259.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X259.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1417)


(Start cutting path id: path1415)
(Change tool to Default tool)

G00 Z5.000000
G00 X258.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X258.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1415)


(Start cutting path id: path1413)
(Change tool to Default tool)

G00 Z5.000000
G00 X257.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X257.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1413)


(Start cutting path id: path1411)
(Change tool to Default tool)

G00 Z5.000000
G00 X256.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X256.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1411)


(Start cutting path id: path1409)
(Change tool to Default tool)

G00 Z5.000000
G00 X255.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X255.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1409)


(Start cutting path id: path1407)
(Change tool to Default tool)

G00 Z5.000000
G00 X254.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X254.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1407)


(Start cutting path id: path1403)
(Change tool to Default tool)

G00 Z5.000000
G00 X252.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X252.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1403)


(Start cutting path id: path1401)
(Change tool to Default tool)

G00 Z5.000000
G00 X251.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X251.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1401)


(Start cutting path id: path1399)
(Change tool to Default tool)

G00 Z5.000000
G00 X250.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X250.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1399)


(Start cutting path id: path1397)
(Change tool to Default tool)

G00 Z5.000000
G00 X249.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X249.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1397)


(Start cutting path id: path1395)
(Change tool to Default tool)

G00 Z5.000000
G00 X248.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X248.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1395)


(Start cutting path id: path1393)
(Change tool to Default tool)

G00 Z5.000000
G00 X247.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X247.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1393)


(Start cutting path id: path1391)
(Change tool to Default tool)

G00 Z5.000000
G00 X246.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X246.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1391)


(Start cutting path id: path1389)
(Change tool to Default tool)

G00 Z5.000000
G00 X245.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X245.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1389)


(Start cutting path id: path1387)
(Change tool to Default tool)

G00 Z5.000000
G00 X244.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X244.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1387)


(Start cutting path id: path1383)
(Change tool to Default tool)

G00 Z5.000000
G00 X242.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X242.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1383)


(Start cutting path id: path1381)
(Change tool to Default tool)

G00 Z5.000000
G00 X241.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X241.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1381)


(Start cutting path id: path1379)
(Change tool to Default tool)

G00 Z5.000000
G00 X240.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X240.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1379)


(Start cutting path id: path1377)
(Change tool to Default tool)

G00 Z5.000000
G00 X239.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X239.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1377)


(Start cutting path id: path1375)
(Change tool to Default tool)

G00 Z5.000000
G00 X238.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X238.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1375)


(Start cutting path id: path1373)
(Change tool to Default tool)

G00 Z5.000000
G00 X237.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X237.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1373)


(Start cutting path id: path1371)
(Change tool to Default tool)

G00 Z5.000000
G00 X236.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X236.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1371)


(Start cutting path id: path1369)
(Change tool to Default tool)

G00 Z5.000000
G00 X235.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X235.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1369)


(Start cutting path id: path1367)
(Change tool to Default tool)

G00 Z5.000000
G00 X234.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X234.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1367)


(Start cutting path id: path1363)
(Change tool to Default tool)

G00 Z5.000000
G00 X232.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X232.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1363)


(Start cutting path id: path1361)
(Change tool to Default tool)

G00 Z5.000000
G00 X231.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X231.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1361)


(Start cutting path id: path1359)
(Change tool to Default tool)

G00 Z5.000000
G00 X230.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X230.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1359)


(Start cutting path id: path1357)
(Change tool to Default tool)

G00 Z5.000000
G00 X229.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X229.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1357)


(Start cutting path id: path1355)
(Change tool to Default tool)

G00 Z5.000000
G00 X228.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X228.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1355)


(Start cutting path id: path1353)
(Change tool to Default tool)

G00 Z5.000000
G00 X227.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X227.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1353)


(Start cutting path id: path1351)
(Change tool to Default tool)

G00 Z5.000000
G00 X226.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X226.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1351)


(Start cutting path id: path1349)
(Change tool to Default tool)

G00 Z5.000000
G00 X225.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X225.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1349)


(Start cutting path id: path1347)
(Change tool to Default tool)

G00 Z5.000000
G00 X224.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X224.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1347)


(Start cutting path id: path1343)
(Change tool to Default tool)

G00 Z5.000000
G00 X222.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X222.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1343)


(Start cutting path id: path1341)
(Change tool to Default tool)

G00 Z5.000000
G00 X221.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X221.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1341)


(Start cutting path id: path1339)
(Change tool to Default tool)

G00 Z5.000000
G00 X220.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X220.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1339)


(Start cutting path id: path1337)
(Change tool to Default tool)

G00 Z5.000000
G00 X219.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X219.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1337)


(Start cutting path id: path1335)
(Change tool to Default tool)

G00 Z5.000000
G00 X218.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X218.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1335)


(Start cutting path id: path1333)
(Change tool to Default tool)

G00 Z5.000000
G00 X217.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X217.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1333)


(Start cutting path id: path1331)
(Change tool to Default tool)

G00 Z5.000000
G00 X216.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X216.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1331)


(Start cutting path id: path1329)
(Change tool to Default tool)

G00 Z5.000000
G00 X215.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X215.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1329)


(Start cutting path id: path1327)
(Change tool to Default tool)

G00 Z5.000000
G00 X214.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X214.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1327)


(Start cutting path id: path1323)
(Change tool to Default tool)

G00 Z5.000000
G00 X212.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X212.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1323)


(Start cutting path id: path1321)
(Change tool to Default tool)

G00 Z5.000000
G00 X211.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X211.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1321)


(Start cutting path id: path1319)
(Change tool to Default tool)

G00 Z5.000000
G00 X210.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X210.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1319)


(Start cutting path id: path1317)
(Change tool to Default tool)

G00 Z5.000000
G00 X209.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X209.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1317)


(Start cutting path id: path1315)
(Change tool to Default tool)

G00 Z5.000000
G00 X208.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X208.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1315)


(Start cutting path id: path1313)
(Change tool to Default tool)

G00 Z5.000000
G00 X207.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X207.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1313)


(Start cutting path id: path1311)
(Change tool to Default tool)

G00 Z5.000000
G00 X206.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X206.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1311)


(Start cutting path id: path1309)
(Change tool to Default tool)

G00 Z5.000000
G00 X205.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X205.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1309)


(Start cutting path id: path1307)
(Change tool to Default tool)

G00 Z5.000000
G00 X204.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X204.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1307)


(Start cutting path id: path1303)
(Change tool to Default tool)

G00 Z5.000000
G00 X202.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X202.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1303)


(Start cutting path id: path1301)
(Change tool to Default tool)

G00 Z5.000000
G00 X201.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X201.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1301)


(Start cutting path id: path1299)
(Change tool to Default tool)

G00 Z5.000000
G00 X200.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X200.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1299)


(Start cutting path id: path1297)
(Change tool to Default tool)

G00 Z5.000000
G00 X199.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X199.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1297)


(Start cutting path id: path1295)
(Change tool to Default tool)

G00 Z5.000000
G00 X198.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X198.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1295)


(Start cutting path id: path1293)
(Change tool to Default tool)

G00 Z5.000000
G00 X197.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X197.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1293)


(Start cutting path id: path1291)
(Change tool to Default tool)

G00 Z5.000000
G00 X196.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X196.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1291)


(Start cutting path id: path1289)
(Change tool to Default tool)

G00 Z5.000000
G00 X195.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X195.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1289)


(Start cutting path id: path1287)
(Change tool to Default tool)

G00 Z5.000000
G00 X194.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X194.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1287)


(Start cutting path id: path1283)
(Change tool to Default tool)

G00 Z5.000000
G00 X192.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X192.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1283)


(Start cutting path id: path1281)
(Change tool to Default tool)

G00 Z5.000000
G00 X191.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X191.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1281)


(Start cutting path id: path1279)
(Change tool to Default tool)

G00 Z5.000000
G00 X190.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X190.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1279)


(Start cutting path id: path1277)
(Change tool to Default tool)

G00 Z5.000000
G00 X189.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X189.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1277)


(Start cutting path id: path1275)
(Change tool to Default tool)

G00 Z5.000000
G00 X188.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X188.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1275)


(Start cutting path id: path1273)
(Change tool to Default tool)

G00 Z5.000000
G00 X187.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X187.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1273)


(Start cutting path id: path1271)
(Change tool to Default tool)

G00 Z5.000000
G00 X186.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X186.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1271)


(Start cutting path id: path1269)
(Change tool to Default tool)

G00 Z5.000000
G00 X185.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X185.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1269)


(Start cutting path id: path1267)
(Change tool to Default tool)

G00 Z5.000000
G00 X184.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X184.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1267)


(Start cutting path id: path1263)
(Change tool to Default tool)

G00 Z5.000000
G00 X182.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X182.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1263)


(Start cutting path id: path1261)
(Change tool to Default tool)

G00 Z5.000000
G00 X181.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X181.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1261)


(Start cutting path id: path1259)
(Change tool to Default tool)

G00 Z5.000000
G00 X180.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X180.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1259)


(Start cutting path id: path1257)
(Change tool to Default tool)

G00 Z5.000000
G00 X179.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X179.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1257)


(Start cutting path id: path1255)
(Change tool to Default tool)

G00 Z5.000000
G00 X178.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X178.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1255)


(Start cutting path id: path1253)
(Change tool to Default tool)

G00 Z5.000000
G00 X177.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X177.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1253)


(Start cutting path id: path1251)
(Change tool to Default tool)

G00 Z5.000000
G00 X176.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X176.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1251)


(Start cutting path id: path1249)
(Change tool to Default tool)

G00 Z5.000000
G00 X175.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X175.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1249)


(Start cutting path id: path1247)
(Change tool to Default tool)

G00 Z5.000000
G00 X174.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X174.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1247)


(Start cutting path id: path1243)
(Change tool to Default tool)

G00 Z5.000000
G00 X172.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X172.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1243)


(Start cutting path id: path1241)
(Change tool to Default tool)

G00 Z5.000000
G00 X171.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X171.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1241)


(Start cutting path id: path1239)
(Change tool to Default tool)

G00 Z5.000000
G00 X170.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X170.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1239)


(Start cutting path id: path1237)
(Change tool to Default tool)

G00 Z5.000000
G00 X169.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X169.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1237)


(Start cutting path id: path1235)
(Change tool to Default tool)

G00 Z5.000000
G00 X168.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X168.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1235)


(Start cutting path id: path1233)
(Change tool to Default tool)

G00 Z5.000000
G00 X167.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X167.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1233)


(Start cutting path id: path1231)
(Change tool to Default tool)

G00 Z5.000000
G00 X166.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X166.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1231)


(Start cutting path id: path1229)
(Change tool to Default tool)

G00 Z5.000000
G00 X165.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X165.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1229)


(Start cutting path id: path1227)
(Change tool to Default tool)

G00 Z5.000000
G00 X164.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X164.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1227)


(Start cutting path id: path1223)
(Change tool to Default tool)

G00 Z5.000000
G00 X162.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X162.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1223)


(Start cutting path id: path1221)
(Change tool to Default tool)

G00 Z5.000000
G00 X161.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X161.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1221)


(Start cutting path id: path1219)
(Change tool to Default tool)

G00 Z5.000000
G00 X160.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X160.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1219)


(Start cutting path id: path1217)
(Change tool to Default tool)

G00 Z5.000000
G00 X159.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X159.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1217)


(Start cutting path id: path1215)
(Change tool to Default tool)

G00 Z5.000000
G00 X158.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X158.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1215)


(Start cutting path id: path1213)
(Change tool to Default tool)

G00 Z5.000000
G00 X157.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X157.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1213)


(Start cutting path id: path1211)
(Change tool to Default tool)

G00 Z5.000000
G00 X156.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X156.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1211)


(Start cutting path id: path1209)
(Change tool to Default tool)

G00 Z5.000000
G00 X155.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X155.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1209)


(Start cutting path id: path1207)
(Change tool to Default tool)

G00 Z5.000000
G00 X154.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X154.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1207)


(Start cutting path id: path1203)
(Change tool to Default tool)

G00 Z5.000000
G00 X152.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X152.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1203)


(Start cutting path id: path1201)
(Change tool to Default tool)

G00 Z5.000000
G00 X151.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X151.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1201)


(Start cutting path id: path1199)
(Change tool to Default tool)

G00 Z5.000000
G00 X150.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X150.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1199)


(Start cutting path id: path1197)
(Change tool to Default tool)

G00 Z5.000000
G00 X149.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X149.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1197)


(Start cutting path id: path1195)
(Change tool to Default tool)

G00 Z5.000000
G00 X148.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X148.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1195)


(Start cutting path id: path1193)
(Change tool to Default tool)

G00 Z5.000000
G00 X147.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X147.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1193)


(Start cutting path id: path1191)
(Change tool to Default tool)

G00 Z5.000000
G00 X146.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X146.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1191)


(Start cutting path id: path1189)
(Change tool to Default tool)

G00 Z5.000000
G00 X145.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X145.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1189)


(Start cutting path id: path1187)
(Change tool to Default tool)

G00 Z5.000000
G00 X144.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X144.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1187)


(Start cutting path id: path1183)
(Change tool to Default tool)

G00 Z5.000000
G00 X142.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X142.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1183)


(Start cutting path id: path1181)
(Change tool to Default tool)

G00 Z5.000000
G00 X141.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X141.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1181)


(Start cutting path id: path1179)
(Change tool to Default tool)

G00 Z5.000000
G00 X140.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X140.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1179)


(Start cutting path id: path1177)
(Change tool to Default tool)

G00 Z5.000000
G00 X139.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X139.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1177)


(Start cutting path id: path1175)
(Change tool to Default tool)

G00 Z5.000000
G00 X138.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X138.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1175)


(Start cutting path id: path1173)
(Change tool to Default tool)

G00 Z5.000000
G00 X137.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X137.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1173)


(Start cutting path id: path1171)
(Change tool to Default tool)

G00 Z5.000000
G00 X136.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X136.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1171)


(Start cutting path id: path1169)
(Change tool to Default tool)

G00 Z5.000000
G00 X135.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X135.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1169)


(Start cutting path id: path1167)
(Change tool to Default tool)

G00 Z5.000000
G00 X134.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X134.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1167)


(Start cutting path id: path1163)
(Change tool to Default tool)

G00 Z5.000000
G00 X132.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X132.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1163)


(Start cutting path id: path1161)
(Change tool to Default tool)

G00 Z5.000000
G00 X131.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X131.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1161)


(Start cutting path id: path1159)
(Change tool to Default tool)

G00 Z5.000000
G00 X130.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X130.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1159)


(Start cutting path id: path1157)
(Change tool to Default tool)

G00 Z5.000000
G00 X129.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X129.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1157)


(Start cutting path id: path1155)
(Change tool to Default tool)

G00 Z5.000000
G00 X128.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X128.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1155)


(Start cutting path id: path1153)
(Change tool to Default tool)

G00 Z5.000000
G00 X127.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X127.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1153)


(Start cutting path id: path1151)
(Change tool to Default tool)

G00 Z5.000000
G00 X126.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X126.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1151)


(Start cutting path id: path1149)
(Change tool to Default tool)

G00 Z5.000000
G00 X125.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X125.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1149)


(Start cutting path id: path1147)
(Change tool to Default tool)

G00 Z5.000000
G00 X124.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X124.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1147)


(Start cutting path id: path1143)
(Change tool to Default tool)

G00 Z5.000000
G00 X122.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X122.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1143)


(Start cutting path id: path1141)
(Change tool to Default tool)

G00 Z5.000000
G00 X121.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X121.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1141)


(Start cutting path id: path1139)
(Change tool to Default tool)

G00 Z5.000000
G00 X120.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X120.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1139)


(Start cutting path id: path1137)
(Change tool to Default tool)

G00 Z5.000000
G00 X119.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X119.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1137)


(Start cutting path id: path1135)
(Change tool to Default tool)

G00 Z5.000000
G00 X118.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X118.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1135)


(Start cutting path id: path1133)
(Change tool to Default tool)

G00 Z5.000000
G00 X117.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X117.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1133)


(Start cutting path id: path1131)
(Change tool to Default tool)

G00 Z5.000000
G00 X116.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X116.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1131)


(Start cutting path id: path1129)
(Change tool to Default tool)

G00 Z5.000000
G00 X115.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X115.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1129)


(Start cutting path id: path1127)
(Change tool to Default tool)

G00 Z5.000000
G00 X114.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X114.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1127)


(Start cutting path id: path1123)
(Change tool to Default tool)

G00 Z5.000000
G00 X112.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X112.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1123)


(Start cutting path id: path1121)
(Change tool to Default tool)

G00 Z5.000000
G00 X111.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X111.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1121)


(Start cutting path id: path1119)
(Change tool to Default tool)

G00 Z5.000000
G00 X110.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X110.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1119)


(Start cutting path id: path1117)
(Change tool to Default tool)

G00 Z5.000000
G00 X109.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X109.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1117)


(Start cutting path id: path1115)
(Change tool to Default tool)

G00 Z5.000000
G00 X108.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X108.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1115)


(Start cutting path id: path1113)
(Change tool to Default tool)

G00 Z5.000000
G00 X107.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X107.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1113)


(Start cutting path id: path1111)
(Change tool to Default tool)

G00 Z5.000000
G00 X106.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X106.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1111)


(Start cutting path id: path1109)
(Change tool to Default tool)

G00 Z5.000000
G00 X105.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X105.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1109)


(Start cutting path id: path1107)
(Change tool to Default tool)

G00 Z5.000000
G00 X104.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X104.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1107)


(Start cutting path id: path1103)
(Change tool to Default tool)

G00 Z5.000000
G00 X102.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X102.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1103)


(Start cutting path id: path1101)
(Change tool to Default tool)

G00 Z5.000000
G00 X101.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X101.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1101)


(Start cutting path id: path1099)
(Change tool to Default tool)

G00 Z5.000000
G00 X100.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X100.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1099)


(Start cutting path id: path1097)
(Change tool to Default tool)

G00 Z5.000000
G00 X99.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X99.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1097)


(Start cutting path id: path1095)
(Change tool to Default tool)

G00 Z5.000000
G00 X98.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X98.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1095)


(Start cutting path id: path1093)
(Change tool to Default tool)

G00 Z5.000000
G00 X97.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X97.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1093)


(Start cutting path id: path1091)
(Change tool to Default tool)

G00 Z5.000000
G00 X96.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X96.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1091)


(Start cutting path id: path1089)
(Change tool to Default tool)

G00 Z5.000000
G00 X95.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X95.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1089)


(Start cutting path id: path1087)
(Change tool to Default tool)

G00 Z5.000000
G00 X94.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X94.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1087)


(Start cutting path id: path1083)
(Change tool to Default tool)

G00 Z5.000000
G00 X92.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X92.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1083)


(Start cutting path id: path1081)
(Change tool to Default tool)

G00 Z5.000000
G00 X91.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X91.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1081)


(Start cutting path id: path1079)
(Change tool to Default tool)

G00 Z5.000000
G00 X90.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X90.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1079)


(Start cutting path id: path1077)
(Change tool to Default tool)

G00 Z5.000000
G00 X89.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X89.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1077)


(Start cutting path id: path1075)
(Change tool to Default tool)

G00 Z5.000000
G00 X88.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X88.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1075)


(Start cutting path id: path1073)
(Change tool to Default tool)

G00 Z5.000000
G00 X87.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X87.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1073)


(Start cutting path id: path1071)
(Change tool to Default tool)

G00 Z5.000000
G00 X86.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X86.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1071)


(Start cutting path id: path1069)
(Change tool to Default tool)

G00 Z5.000000
G00 X85.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X85.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1069)


(Start cutting path id: path1067)
(Change tool to Default tool)

G00 Z5.000000
G00 X84.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X84.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1067)


(Start cutting path id: path1063)
(Change tool to Default tool)

G00 Z5.000000
G00 X82.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X82.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1063)


(Start cutting path id: path1061)
(Change tool to Default tool)

G00 Z5.000000
G00 X81.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X81.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1061)


(Start cutting path id: path1059)
(Change tool to Default tool)

G00 Z5.000000
G00 X80.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X80.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1059)


(Start cutting path id: path1057)
(Change tool to Default tool)

G00 Z5.000000
G00 X79.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X79.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1057)


(Start cutting path id: path1055)
(Change tool to Default tool)

G00 Z5.000000
G00 X78.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X78.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1055)


(Start cutting path id: path1053)
(Change tool to Default tool)

G00 Z5.000000
G00 X77.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X77.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1053)


(Start cutting path id: path1051)
(Change tool to Default tool)

G00 Z5.000000
G00 X76.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X76.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1051)


(Start cutting path id: path1049)
(Change tool to Default tool)

G00 Z5.000000
G00 X75.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X75.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1049)


(Start cutting path id: path1047)
(Change tool to Default tool)

G00 Z5.000000
G00 X74.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X74.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1047)


(Start cutting path id: path1043)
(Change tool to Default tool)

G00 Z5.000000
G00 X72.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X72.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1043)


(Start cutting path id: path1041)
(Change tool to Default tool)

G00 Z5.000000
G00 X71.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X71.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1041)


(Start cutting path id: path1039)
(Change tool to Default tool)

G00 Z5.000000
G00 X70.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X70.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1039)


(Start cutting path id: path1037)
(Change tool to Default tool)

G00 Z5.000000
G00 X69.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X69.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1037)


(Start cutting path id: path1035)
(Change tool to Default tool)

G00 Z5.000000
G00 X68.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X68.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1035)


(Start cutting path id: path1033)
(Change tool to Default tool)

G00 Z5.000000
G00 X67.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X67.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1033)


(Start cutting path id: path1031)
(Change tool to Default tool)

G00 Z5.000000
G00 X66.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X66.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1031)


(Start cutting path id: path1029)
(Change tool to Default tool)

G00 Z5.000000
G00 X65.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X65.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1029)


(Start cutting path id: path1027)
(Change tool to Default tool)

G00 Z5.000000
G00 X64.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X64.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1027)


(Start cutting path id: path1023)
(Change tool to Default tool)

G00 Z5.000000
G00 X62.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X62.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1023)


(Start cutting path id: path1021)
(Change tool to Default tool)

G00 Z5.000000
G00 X61.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X61.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1021)


(Start cutting path id: path1019)
(Change tool to Default tool)

G00 Z5.000000
G00 X60.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X60.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1019)


(Start cutting path id: path1017)
(Change tool to Default tool)

G00 Z5.000000
G00 X59.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X59.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1017)


(Start cutting path id: path1015)
(Change tool to Default tool)

G00 Z5.000000
G00 X58.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X58.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1015)


(Start cutting path id: path1013)
(Change tool to Default tool)

G00 Z5.000000
G00 X57.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X57.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1013)


(Start cutting path id: path1011)
(Change tool to Default tool)

G00 Z5.000000
G00 X56.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X56.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1011)


(Start cutting path id: path1009)
(Change tool to Default tool)

G00 Z5.000000
G00 X55.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X55.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1009)


(Start cutting path id: path1007)
(Change tool to Default tool)

G00 Z5.000000
G00 X54.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X54.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1007)


(Start cutting path id: path1003)
(Change tool to Default tool)

G00 Z5.000000
G00 X52.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X52.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1003)


(Start cutting path id: path1001)
(Change tool to Default tool)

G00 Z5.000000
G00 X51.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X51.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path1001)


(Start cutting path id: path999)
(Change tool to Default tool)

G00 Z5.000000
G00 X50.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X50.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path999)


(Start cutting path id: path997)
(Change tool to Default tool)

G00 Z5.000000
G00 X49.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X49.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path997)


(Start cutting path id: path995)
(Change tool to Default tool)

G00 Z5.000000
G00 X48.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X48.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path995)


(Start cutting path id: path993)
(Change tool to Default tool)

G00 Z5.000000
G00 X47.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X47.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path993)


(Start cutting path id: path991)
(Change tool to Default tool)

G00 Z5.000000
G00 X46.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X46.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path991)


(Start cutting path id: path989)
(Change tool to Default tool)

G00 Z5.000000
G00 X45.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X45.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path989)


(Start cutting path id: path987)
(Change tool to Default tool)

G00 Z5.000000
G00 X44.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X44.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path987)


(Start cutting path id: path983)
(Change tool to Default tool)

G00 Z5.000000
G00 X42.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X42.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path983)


(Start cutting path id: path981)
(Change tool to Default tool)

G00 Z5.000000
G00 X41.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X41.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path981)


(Start cutting path id: path979)
(Change tool to Default tool)

G00 Z5.000000
G00 X40.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X40.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path979)


(Start cutting path id: path977)
(Change tool to Default tool)

G00 Z5.000000
G00 X39.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X39.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path977)


(Start cutting path id: path975)
(Change tool to Default tool)

G00 Z5.000000
G00 X38.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X38.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path975)


(Start cutting path id: path973)
(Change tool to Default tool)

G00 Z5.000000
G00 X37.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X37.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path973)


(Start cutting path id: path971)
(Change tool to Default tool)

G00 Z5.000000
G00 X36.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X36.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path971)


(Start cutting path id: path969)
(Change tool to Default tool)

G00 Z5.000000
G00 X35.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X35.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path969)


(Start cutting path id: path967)
(Change tool to Default tool)

G00 Z5.000000
G00 X34.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X34.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path967)


(Start cutting path id: path963)
(Change tool to Default tool)

G00 Z5.000000
G00 X32.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X32.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path963)


(Start cutting path id: path961)
(Change tool to Default tool)

G00 Z5.000000
G00 X31.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X31.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path961)


(Start cutting path id: path959)
(Change tool to Default tool)

G00 Z5.000000
G00 X30.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X30.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path959)


(Start cutting path id: path957)
(Change tool to Default tool)

G00 Z5.000000
G00 X29.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X29.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path957)


(Start cutting path id: path955)
(Change tool to Default tool)

G00 Z5.000000
G00 X28.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X28.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path955)


(Start cutting path id: path953)
(Change tool to Default tool)

G00 Z5.000000
G00 X27.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X27.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path953)


(Start cutting path id: path951)
(Change tool to Default tool)

G00 Z5.000000
G00 X26.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X26.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path951)


(Start cutting path id: path949)
(Change tool to Default tool)

G00 Z5.000000
G00 X25.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X25.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path949)


(Start cutting path id: path947)
(Change tool to Default tool)

G00 Z5.000000
G00 X24.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X24.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path947)


(Start cutting path id: path934)
(Change tool to Default tool)

G00 Z5.000000
G00 X22.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X22.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path934)


(Start cutting path id: path932)
(Change tool to Default tool)

G00 Z5.000000
G00 X21.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X21.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path932)


(Start cutting path id: path930)
(Change tool to Default tool)

G00 Z5.000000
G00 X20.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X20.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path930)


(Start cutting path id: path928)
(Change tool to Default tool)

G00 Z5.000000
G00 X19.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X19.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path928)


(Start cutting path id: path926)
(Change tool to Default tool)

G00 Z5.000000
G00 X18.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X18.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path926)


(Start cutting path id: path924)
(Change tool to Default tool)

G00 Z5.000000
G00 X17.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X17.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path924)


(Start cutting path id: path922)
(Change tool to Default tool)

G00 Z5.000000
G00 X16.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X16.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path922)


(Start cutting path id: path920)
(Change tool to Default tool)

G00 Z5.000000
G00 X15.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X15.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path920)


(Start cutting path id: path918)
(Change tool to Default tool)

G00 Z5.000000
G00 X14.562498 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X14.562498 Y187.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path918)


(Start cutting path id: path1522)
(Change tool to Default tool)

G00 Z5.000000
G00 X285.858290 Y180.837770

G01 Z-0.125000 F100.0(Penetrate)
G03 X285.631013 Y180.769933 Z-0.125000 I-0.000000 J-0.414646 F800
G03 X285.453490 Y180.572490 Z-0.125000 I0.284814 J-0.434607
G03 X285.362815 Y180.298447 Z-0.125000 I0.849613 J-0.433140
G03 X285.319130 Y179.778400 Z-0.125000 I3.073564 J-0.520047
G03 X285.362679 Y179.259980 Z-0.125000 I3.107498 J0.000000
G03 X285.453490 Y178.984310 Z-0.125000 I0.953641 J0.161356
G03 X285.630717 Y178.788314 Z-0.125000 I0.459200 J0.237101
G03 X285.858290 Y178.720760 Z-0.125000 I0.227573 J0.349541
G03 X286.087115 Y178.788686 Z-0.125000 I-0.000000 J0.419391
G03 X286.263090 Y178.984310 Z-0.125000 I-0.278068 J0.427099
G03 X286.355093 Y179.260226 Z-0.125000 I-0.853818 J0.437998
G03 X286.399170 Y179.778400 Z-0.125000 I-3.023786 J0.518174
G03 X286.354954 Y180.298199 Z-0.125000 I-3.077482 J-0.000000
G03 X286.263090 Y180.572490 Z-0.125000 I-0.932618 J-0.159819
G03 X286.086817 Y180.769560 Z-0.125000 I-0.457158 J-0.231543
G03 X285.858290 Y180.837770 Z-0.125000 I-0.228527 J-0.348718
G01 X285.858290 Y180.837770 Z-0.125000
G00 Z5.000000

(End cutting path id: path1522)


(Start cutting path id: path1522)
(Change tool to Default tool)

G00 Z5.000000
G00 X285.858290 Y181.113370

G01 Z-0.125000 F100.0(Penetrate)
G02 X286.240538 Y181.019994 Z-0.125000 I-0.000000 J-0.829079 F800
G02 X286.518030 Y180.770590 Z-0.125000 I-0.343664 J-0.661442
G02 X286.675416 Y180.407674 Z-0.125000 I-0.905778 J-0.608393
G02 X286.747120 Y179.778400 Z-0.125000 I-2.725389 J-0.629274
G02 X286.675595 Y179.150700 Z-0.125000 I-2.790095 J-0.000000
G02 X286.518030 Y178.786210 Z-0.125000 I-1.074016 J0.247983
G02 X286.240858 Y178.538188 Z-0.125000 I-0.618585 J0.412402
G02 X285.858290 Y178.445150 Z-0.125000 I-0.382568 J0.740033
G02 X285.475436 Y178.538042 Z-0.125000 I0.000000 J0.835409
G02 X285.196830 Y178.786210 Z-0.125000 I0.343391 J0.665981
G02 X285.040494 Y179.150417 Z-0.125000 I0.921452 J0.611192
G02 X284.969460 Y179.778400 Z-0.125000 I2.740374 J0.627983
G02 X285.040672 Y180.407960 Z-0.125000 I2.818464 J0.000000
G02 X285.196830 Y180.770590 Z-0.125000 I1.066869 J-0.244483
G02 X285.475755 Y181.020139 Z-0.125000 I0.624569 J-0.417436
G02 X285.858290 Y181.113370 Z-0.125000 I0.382535 J-0.738174
G01 X285.858290 Y181.113370 Z-0.125000
G00 Z5.000000

(End cutting path id: path1522)


(Start cutting path id: path1520)
(Change tool to Default tool)

G00 Z5.000000
G00 X282.780100 Y181.066870

G01 Z-0.125000 F100.0(Penetrate)
G01 X284.433740 Y181.066870 Z-0.125000 F800
G01 X284.433740 Y180.918730 Z-0.125000
G01 X283.500120 Y178.495100 Z-0.125000
G01 X283.136660 Y178.495100 Z-0.125000
G01 X284.015160 Y180.774030 Z-0.125000
G01 X282.780100 Y180.774030 Z-0.125000
G01 X282.780100 Y181.066870 Z-0.125000
G00 Z5.000000

(End cutting path id: path1520)


(Start cutting path id: path1518)
(Change tool to Default tool)

G00 Z5.000000
G00 X280.921470 Y178.787940

G01 Z-0.125000 F100.0(Penetrate)
G01 X282.135860 Y178.787940 Z-0.125000 F800
G01 X282.135860 Y178.495100 Z-0.125000
G01 X280.502890 Y178.495100 Z-0.125000
G01 X280.502890 Y178.787940 Z-0.125000
G02 X280.701755 Y178.992162 Z-0.125000 I26.957893 J-26.051756
G02 X281.042050 Y179.337430 Z-0.125000 I77.395164 J-75.940193
G03 X281.382571 Y179.685768 Z-0.125000 I-27.298787 J27.026769
G03 X281.472680 Y179.783570 Z-0.125000 I-2.059883 J1.988271
G03 X281.629955 Y179.978017 Z-0.125000 I-1.983615 J1.765244
G03 X281.705230 Y180.100520 Z-0.125000 I-0.707632 J0.519198
G03 X281.756729 Y180.235224 Z-0.125000 I-0.589206 J0.302457
G03 X281.772430 Y180.357180 Z-0.125000 I-0.465790 J0.121956
G03 X281.733562 Y180.544757 Z-0.125000 I-0.472058 J-0.000000
G03 X281.627730 Y180.691350 Z-0.125000 I-0.385902 J-0.167101
G03 X281.470747 Y180.784130 Z-0.125000 I-0.306148 J-0.338803
G03 X281.253940 Y180.820540 Z-0.125000 I-0.216807 J-0.627294
G03 X281.092301 Y180.807369 Z-0.125000 I-0.000000 J-0.998456
G03 X280.907710 Y180.763740 Z-0.125000 I0.221111 J-1.347806
G03 X280.731116 Y180.697016 Z-0.125000 I0.496656 J-1.581516
G03 X280.520130 Y180.591480 Z-0.125000 I1.051373 J-2.365559
G01 X280.520130 Y180.942880 Z-0.125000
G02 X280.732619 Y181.019929 Z-0.125000 I1.238011 J-3.082707
G02 X280.912880 Y181.070350 Z-0.125000 I0.703311 J-2.166983
G02 X281.096595 Y181.103787 Z-0.125000 I0.414522 J-1.756090
G02 X281.247050 Y181.113450 Z-0.125000 I0.150455 J-1.166533
G02 X281.625562 Y181.055507 Z-0.125000 I0.000000 J-1.265295
G02 X281.884390 Y180.913640 Z-0.125000 I-0.224889 J-0.717335
G02 X282.057477 Y180.683721 Z-0.125000 I-0.412339 J-0.490526
G02 X282.122100 Y180.379650 Z-0.125000 I-0.683062 J-0.304071
G02 X282.106713 Y180.224282 Z-0.125000 I-0.792098 J0.000000
G02 X282.061800 Y180.078200 Z-0.125000 I-0.744249 J0.148874
G02 X281.991436 Y179.943966 Z-0.125000 I-0.782630 J0.324688
G02 X281.846490 Y179.744030 Z-0.125000 I-1.891008 J1.218401
G02 X281.802283 Y179.695141 Z-0.125000 I-1.096934 J0.947452
G02 X281.572600 Y179.454640 Z-0.125000 I-26.798550 J25.363194
G02 X281.341431 Y179.217270 Z-0.125000 I-80.785226 J78.443675
G02 X280.921480 Y178.788020 Z-0.125000 I-264.602657 J258.450210
G01 X280.921470 Y178.787940 Z-0.125000
G00 Z5.000000

(End cutting path id: path1518)


(Start cutting path id: path1515)
(Change tool to Default tool)

G00 Z5.000000
G00 X13.624998 Y180.837770

G01 Z-0.125000 F100.0(Penetrate)
G03 X13.397723 Y180.769934 Z-0.125000 I0.000000 J-0.414643 F800
G03 X13.220199 Y180.572490 Z-0.125000 I0.284817 J-0.434611
G03 X13.129525 Y180.298447 Z-0.125000 I0.849618 J-0.433139
G03 X13.085840 Y179.778400 Z-0.125000 I3.073587 J-0.520047
G03 X13.129389 Y179.259980 Z-0.125000 I3.107522 J-0.000000
G03 X13.220199 Y178.984310 Z-0.125000 I0.953646 J0.161356
G03 X13.397427 Y178.788314 Z-0.125000 I0.459204 J0.237105
G03 X13.624998 Y178.720760 Z-0.125000 I0.227571 J0.349537
G03 X13.853823 Y178.788686 Z-0.125000 I-0.000000 J0.419389
G03 X14.029796 Y178.984310 Z-0.125000 I-0.278066 J0.427093
G03 X14.121800 Y179.260226 Z-0.125000 I-0.853808 J0.437999
G03 X14.165878 Y179.778400 Z-0.125000 I-3.023740 J0.518174
G03 X14.121662 Y180.298198 Z-0.125000 I-3.077436 J-0.000000
G03 X14.029796 Y180.572490 Z-0.125000 I-0.932610 J-0.159820
G03 X13.853525 Y180.769560 Z-0.125000 I-0.457154 J-0.231538
G03 X13.624998 Y180.837770 Z-0.125000 I-0.228527 J-0.348715
G01 X13.624998 Y180.837770 Z-0.125000
G00 Z5.000000

(End cutting path id: path1515)


(Start cutting path id: path1515)
(Change tool to Default tool)

G00 Z5.000000
G00 X13.624998 Y181.113370

G01 Z-0.125000 F100.0(Penetrate)
G02 X14.007245 Y181.019994 Z-0.125000 I-0.000000 J-0.829072 F800
G02 X14.284734 Y180.770590 Z-0.125000 I-0.343662 J-0.661433
G02 X14.442125 Y180.407673 Z-0.125000 I-0.905755 J-0.608399
G02 X14.513832 Y179.778400 Z-0.125000 I-2.725288 J-0.629273
G02 X14.442305 Y179.150702 Z-0.125000 I-2.789997 J0.000000
G02 X14.284734 Y178.786210 Z-0.125000 I-1.073999 J0.247988
G02 X14.007565 Y178.538188 Z-0.125000 I-0.618580 J0.412393
G02 X13.624998 Y178.445150 Z-0.125000 I-0.382567 J0.740026
G02 X13.242144 Y178.538043 Z-0.125000 I-0.000000 J0.835408
G02 X12.963539 Y178.786210 Z-0.125000 I0.343390 J0.665978
G02 X12.807198 Y179.150418 Z-0.125000 I0.921435 J0.611197
G02 X12.736163 Y179.778400 Z-0.125000 I2.740298 J0.627982
G02 X12.807377 Y180.407959 Z-0.125000 I2.818389 J0.000000
G02 X12.963539 Y180.770590 Z-0.125000 I1.066856 J-0.244487
G02 X13.242463 Y181.020139 Z-0.125000 I0.624567 J-0.417433
G02 X13.624998 Y181.113370 Z-0.125000 I0.382535 J-0.738173
G01 X13.624998 Y181.113370 Z-0.125000
G00 Z5.000000

(End cutting path id: path1515)


(Start cutting path id: path890)
(Change tool to Default tool)

G00 Z5.000000
G00 X283.625000 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X283.625000 Y182.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path890)


(Start cutting path id: path888)
(Change tool to Default tool)

G00 Z5.000000
G00 X273.625000 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X273.625000 Y182.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path888)


(Start cutting path id: path886)
(Change tool to Default tool)

G00 Z5.000000
G00 X263.625000 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X263.625000 Y182.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path886)


(Start cutting path id: path884)
(Change tool to Default tool)

G00 Z5.000000
G00 X253.625000 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X253.625000 Y182.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path884)


(Start cutting path id: path882)
(Change tool to Default tool)

G00 Z5.000000
G00 X243.625000 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X243.625000 Y182.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path882)


(Start cutting path id: path880)
(Change tool to Default tool)

G00 Z5.000000
G00 X233.625000 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X233.625000 Y182.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path880)


(Start cutting path id: path878)
(Change tool to Default tool)

G00 Z5.000000
G00 X223.625000 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X223.625000 Y182.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path878)


(Start cutting path id: path876)
(Change tool to Default tool)

G00 Z5.000000
G00 X213.625000 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X213.625000 Y182.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path876)


(Start cutting path id: path874)
(Change tool to Default tool)

G00 Z5.000000
G00 X203.625000 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X203.625000 Y182.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path874)


(Start cutting path id: path872)
(Change tool to Default tool)

G00 Z5.000000
G00 X193.625000 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X193.625000 Y182.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path872)


(Start cutting path id: path870)
(Change tool to Default tool)

G00 Z5.000000
G00 X183.625000 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X183.625000 Y182.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path870)


(Start cutting path id: path868)
(Change tool to Default tool)

G00 Z5.000000
G00 X173.625000 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X173.625000 Y182.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path868)


(Start cutting path id: path866)
(Change tool to Default tool)

G00 Z5.000000
G00 X163.625000 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X163.625000 Y182.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path866)


(Start cutting path id: path864)
(Change tool to Default tool)

G00 Z5.000000
G00 X153.625000 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X153.625000 Y182.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path864)


(Start cutting path id: path862)
(Change tool to Default tool)

G00 Z5.000000
G00 X143.625000 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X143.625000 Y182.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path862)


(Start cutting path id: path860)
(Change tool to Default tool)

G00 Z5.000000
G00 X133.625000 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X133.625000 Y182.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path860)


(Start cutting path id: path858)
(Change tool to Default tool)

G00 Z5.000000
G00 X123.625000 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X123.625000 Y182.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path858)


(Start cutting path id: path856)
(Change tool to Default tool)

G00 Z5.000000
G00 X113.625000 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X113.625000 Y182.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path856)


(Start cutting path id: path854)
(Change tool to Default tool)

G00 Z5.000000
G00 X103.625000 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X103.625000 Y182.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path854)


(Start cutting path id: path852)
(Change tool to Default tool)

G00 Z5.000000
G00 X93.624998 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X93.624998 Y182.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path852)


(Start cutting path id: path850)
(Change tool to Default tool)

G00 Z5.000000
G00 X83.624998 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X83.624998 Y182.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path850)


(Start cutting path id: path846)
(Change tool to Default tool)

G00 Z5.000000
G00 X73.624998 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X73.624998 Y182.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path846)


(Start cutting path id: path844)
(Change tool to Default tool)

G00 Z5.000000
G00 X63.624998 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X63.624998 Y182.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path844)


(Start cutting path id: path842)
(Change tool to Default tool)

G00 Z5.000000
G00 X53.624998 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X53.624998 Y182.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path842)


(Start cutting path id: path840)
(Change tool to Default tool)

G00 Z5.000000
G00 X43.624998 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X43.624998 Y182.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path840)


(Start cutting path id: path838)
(Change tool to Default tool)

G00 Z5.000000
G00 X33.624998 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X33.624998 Y182.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path838)


(Start cutting path id: path836)
(Change tool to Default tool)

G00 Z5.000000
G00 X23.624998 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X23.624998 Y182.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path836)


(Start cutting path id: path832)
(Change tool to Default tool)

G00 Z5.000000
G00 X13.624998 Y192.669830

G01 Z-0.125000 F100.0(Penetrate)
G01 X13.624998 Y182.669830 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path832)


(Start cutting path id: path821)
(Change tool to Default tool)

G00 Z5.000000
G00 X13.499998 Y192.537330

G01 Z-0.125000 F100.0(Penetrate)
G01 X283.500000 Y192.537330 Z-0.125000 F800
G00 Z5.000000

(End cutting path id: path821)


(Start cutting path id: path819)
(Change tool to Default tool)

G00 Z5.000000
G00 X198.374870 Y105.000000

G01 Z-0.125000 F100.0(Penetrate)
G02 X194.578373 Y85.913713 Z-0.125000 I-49.874866 J-0.000004 F800
G02 X183.766860 Y69.733140 Z-0.125000 I-46.078369 J19.086283
G02 X167.586287 Y58.921627 Z-0.125000 I-35.266856 J35.266856
G02 X148.500000 Y55.125130 Z-0.125000 I-19.086283 J46.078369
G02 X129.413714 Y58.921628 Z-0.125000 I-0.000000 J49.874866
G02 X113.233143 Y69.733141 Z-0.125000 I19.086286 J46.078368
G02 X102.421631 Y85.913714 Z-0.125000 I35.266857 J35.266855
G02 X98.625134 Y105.000000 Z-0.125000 I46.078369 J19.086282
G02 X102.421631 Y124.086286 Z-0.125000 I49.874866 J0.000004
G02 X113.233143 Y140.266859 Z-0.125000 I46.078369 J-19.086282
G02 X129.413714 Y151.078371 Z-0.125000 I35.266857 J-35.266855
G02 X148.500000 Y154.874870 Z-0.125000 I19.086286 J-46.078367
G02 X167.586287 Y151.078373 Z-0.125000 I0.000004 J-49.874866
G02 X183.766860 Y140.266860 Z-0.125000 I-19.086283 J-46.078369
G02 X194.578373 Y124.086287 Z-0.125000 I-35.266856 J-35.266856
G02 X198.374870 Y105.000000 Z-0.125000 I-46.078369 J-19.086283
G01 X198.374870 Y105.000000 Z-0.125000
G00 Z5.000000

(End cutting path id: path819)


(Start cutting path id: rect10)
(Change tool to Default tool)

G00 Z5.000000
G00 X98.625320 Y154.874680

G01 Z-0.125000 F100.0(Penetrate)
G01 X198.374680 Y154.874680 Z-0.125000 F800
G01 X198.374680 Y55.125320 Z-0.125000
G01 X98.625320 Y55.125320 Z-0.125000
G01 X98.625320 Y154.874680 Z-0.125000
G00 Z5.000000

(End cutting path id: rect10)


M05  ; Turn laser off

G28  ; Go to home position
M2  ; Program end
M9  ; Turn off fan
