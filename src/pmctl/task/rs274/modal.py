"""Modal state and the codes of RS-274/NGC: which G and M codes exist, their modal groups, and what
this machine makes of the ones it does not run (refused with a kind and a reason).

G codes are handled as integers, ten times the code (``G38.2`` -> 382, ``G59.3`` -> 593). A line may
hold at most one code of each modal group (``G0 G1`` is an error); group 0 (non-modal) codes that
use axis words (G10 G28 G30 G52 G92) cannot share a line with a motion that uses them too.

:class:`State` is the interpreter's modal state between blocks. Positions are the tool tip in the
workpiece frame W in mm (``pos`` = X Y Z A B, A and B in degrees); offsets are in mm (degrees for
A B); feeds are kept physical (mm/min or mm/rev), as LinuxCNC's canon keeps them, so G20/G21 after an
F does not change the speed.
"""

from __future__ import annotations

MM_PER_INCH = 25.4

G_GROUP = {}
for _grp, _codes in {
    0: (40, 100, 280, 281, 300, 301, 520, 530, 920, 921, 922, 923),
    1: (0, 10, 20, 30, 50, 51, 382, 383, 730, 740, 800, 810, 820, 830, 840, 850, 860, 870, 880, 890),
    2: (170, 180, 190),
    3: (900, 910),
    4: (901, 911),
    5: (930, 940, 950),
    6: (200, 210),
    7: (400, 410, 420, 411, 421),
    8: (430, 431, 490),
    10: (980, 990),
    12: (540, 550, 560, 570, 580, 590, 591, 592, 593),
    13: (610, 611, 640),
    14: (970,),
    16: (1870, 1030, 80),              # Haas G187, G103; G8 (Fanuc look-ahead, LinuxCNC's lathe radius mode): no effect
    17: (150, 500, 501, 690),          # other controllers' cancels of modes pmctl never has (accepted, no effect)
}.items():
    for _c in _codes:
        G_GROUP[_c] = _grp

MOTION_CODES = (0, 10, 20, 30, 50, 51, 382, 383, 730, 740, 810, 820, 830, 840, 850, 860, 870, 880, 890)
CYCLES = (730, 740, 810, 820, 830, 840, 850, 860, 870, 880, 890)
AXIS_USERS = (100, 280, 300, 520, 920)        # group-0 codes that use axis words
WCS_CODES = (540, 550, 560, 570, 580, 590, 591, 592, 593)
WCS_NAMES = ("G54", "G55", "G56", "G57", "G58", "G59", "G59.1", "G59.2", "G59.3")

# Codes that exist elsewhere and are refused here: (kind, reason). Kind "machine": this machine lacks
# what the code needs; "unsupported": pmctl does not implement it.
G_REFUSED = {
    52: ("unsupported", "G5.2 NURBS blocks are not supported: have the CAM output lines and arcs"),
    53: ("unsupported", "G5.3 NURBS blocks are not supported: have the CAM output lines and arcs"),
    70: ("machine", "G7 (lathe diameter mode): this machine is a mill"),
    120: ("unsupported", "G12 (circular pocket of another controller) is not supported: program the circle "
                         "with G2/G3"),
    130: ("unsupported", "G13 (circular pocket of another controller) is not supported: program the circle "
                         "with G2/G3"),
    160: ("unsupported", "G16 (polar coordinates of another controller) is not supported: program X and Y"),
    171: ("machine", "G17.1 (the UV plane): this machine has no U V W axes"),
    181: ("machine", "G18.1 (the WU plane): this machine has no U V W axes"),
    191: ("machine", "G19.1 (the VW plane): this machine has no U V W axes"),
    310: ("unsupported", "G31 (skip) is not supported: probe with G38.2 or G38.3"),
    330: ("machine", "G33 (spindle-synchronised motion) needs a spindle encoder, which this machine lacks"),
    331: ("machine", "G33.1 (rigid tapping) needs a spindle encoder, which this machine lacks: use G84 "
                     "with a floating tap holder"),
    384: ("unsupported", "G38.4 (probe away from the workpiece) is not supported: the probe stops on contact "
                         "only (G38.2, G38.3)"),
    385: ("unsupported", "G38.5 (probe away from the workpiece) is not supported: the probe stops on contact "
                         "only (G38.2, G38.3)"),
    432: ("unsupported", "G43.2 (an added tool length offset) is not supported: use G43 H or G43.1"),
    434: ("machine", "G43.4 (tool centre point control of another machine): pmctl's X Y Z are always the "
                     "tool tip and A B its tilt, for this machine's head; a program for another machine's "
                     "kinematics must be posted for this one"),
    435: ("machine", "G43.5 (tool centre point control of another machine): pmctl's X Y Z are always the "
                     "tool tip and A B its tilt, for this machine's head; post the program for this machine"),
    510: ("unsupported", "G51 (scaling of another controller) is not supported: scale the program in the CAM"),
    511: ("unsupported", "G51.1 (mirroring of another controller) is not supported: mirror in the CAM"),
    531: ("machine", "G53.1 (tool axis to a tilted working plane) belongs to another machine's kinematics: "
                     "on this machine A and B set the tool axis directly"),
    650: ("unsupported", "G65 (macro call of another controller) is not supported: use an O-word call "
                         "(o<name> call)"),
    680: ("unsupported", "G68 (coordinate rotation of another controller) is not supported: use G10 L2 "
                         "P<n> R<degrees> for a rotated coordinate system"),
    682: ("machine", "G68.2 (tilted working plane) belongs to another machine's kinematics: post the program "
                     "for this machine, whose A and B tilt the tool directly"),
    700: ("machine", "G70 (a lathe finishing cycle): this machine is a mill; have the CAM output the moves"),
    710: ("machine", "G71 (a lathe roughing cycle): this machine is a mill; have the CAM output the moves"),
    711: ("machine", "G71.1 (a lathe roughing cycle): this machine is a mill; have the CAM output the moves"),
    712: ("machine", "G71.2 (a lathe roughing cycle): this machine is a mill; have the CAM output the moves"),
    720: ("machine", "G72 (a lathe facing cycle): this machine is a mill; have the CAM output the moves"),
    721: ("machine", "G72.1 (a lathe facing cycle): this machine is a mill; have the CAM output the moves"),
    722: ("machine", "G72.2 (a lathe facing cycle): this machine is a mill; have the CAM output the moves"),
    760: ("machine", "G76 (threading cycle) needs a spindle encoder, which this machine lacks"),
    960: ("unsupported", "G96 (constant surface speed) is not supported on this mill: program S in rpm (G97)"),
}

M_GROUP = {}
for _grp, _codes in {
    4: (0, 1, 2, 30, 60),
    6: (6, 61),
    7: (3, 4, 5),
    8: (7, 8, 9),
    5: (62, 63, 64, 65, 66, 67, 68),
    11: (98, 99),
    12: (70, 71, 72, 73),
}.items():
    for _c in _codes:
        M_GROUP[_c] = _grp
M_USER = range(100, 200)

M_REFUSED = {
    10: ("machine", "M10 (a rotary axis brake or clamp of another machine): this machine's A and B tilts have no "
                    "brake to set"),
    11: ("machine", "M11 (a rotary axis brake or clamp release of another machine): this machine's A and B tilts "
                    "have no brake"),
    19: ("machine", "M19 (spindle orientation) needs a spindle with an encoder, which this machine lacks"),
    29: ("machine", "M29 (rigid tapping of another controller) needs a spindle encoder, which this machine "
                    "lacks: use G84 with a floating tap holder"),
    48: ("unsupported", "M48 (enable overrides) is not supported: the overrides are always on at the console"),
    49: ("unsupported", "M49 (disable overrides) is not supported: the overrides are always on at the console"),
    50: ("unsupported", "M50 (feed override control) is not supported"),
    51: ("unsupported", "M51 (spindle override control) is not supported"),
    52: ("unsupported", "M52 (adaptive feed) is not supported"),
    53: ("unsupported", "M53 (feed stop control) is not supported"),
    88: ("machine", "M88 (through-spindle coolant of another controller): this machine has none; use M7 or M8"),
    89: ("machine", "M89 (through-spindle coolant off of another controller): this machine has none"),
    97: ("unsupported", "M97 (local subprogram call of another controller) is not supported: use M98 P<n> "
                        "or an O-word call"),
    428: ("machine", "M428 (tool centre point control of another controller): pmctl's X Y Z are always "
                     "the tool tip and A B its tilt, for this machine's head; post the program for this "
                     "machine"),
    429: ("machine", "M429 (tool centre point control off, of another controller): post the program for "
                     "this machine"),
}

AXES = "xyzab"                         # this machine's axis words
OTHER_AXES = "cuvw"                    # axis words of other machines


SAVED_MODES = ("units", "absolute", "ijk_absolute", "plane", "feed_mode", "cs", "retract", "path", "tolerance",
               "naive_tolerance", "feed", "speed", "spindle", "mist", "flood")    # what M70/M73 keep


class State:
    """The modal state between blocks (copied before a block executes; the copy is kept only if the
    block has no problem)."""

    def __init__(self, pos):
        self.pos = list(pos)               # X Y Z A B: tip in W (mm) and tilt (deg)
        self.units = 1.0                   # mm per program unit (25.4 in G20)
        self.absolute = True               # G90 / G91
        self.ijk_absolute = False          # G90.1 / G91.1
        self.plane = 170                   # G17 / G18 / G19
        self.motion = 800                  # G80: none (a soft reset's G0 is the console's)
        self.feed_mode = 940               # G93 / G94 / G95
        self.feed = 0.0                    # mm/min (G94), mm/rev (G95); 0: not set
        self.speed = 0.0                   # S, rpm
        self.spindle = 0                   # 1 M3, -1 M4, 0 M5
        self.mist = False
        self.flood = False
        self.tool = 0                      # the tool in the spindle (M6 / M61)
        self.selected = None               # the tool T selected (prepared)
        self.tlo = 0.0                     # tool length offset in force, mm (G43 / G43.1; 0 after G49)
        self.tlo_code = 490                # 430 / 431 / 490
        self.comp = 0                      # cutter comp: 0 off, 1 left (G41), 2 right (G42)
        self.comp_radius = 0.0             # mm
        self.comp_first = False            # the next move is the entry move
        self.arc_not_allowed = False       # the move after G40 must be straight (LinuxCNC)
        self.retract = 990                 # G98 / G99: G99 until set, as LinuxCNC (rs274) starts
        self.path = 640                    # G61 / G61.1 / G64
        self.tolerance = 0.0               # G64 P, mm (0: none given)
        self.naive_tolerance = 0.0         # G64 Q, mm
        self.cs = 1                        # 1 = G54 .. 9 = G59.3
        self.g5x = [0.0] * 5               # active coordinate system origin, mm / deg
        self.rotation = 0.0                # its XY rotation, deg
        self.g92 = [0.0] * 5               # G92 / G52 offsets in force
        self.wco = [0.0] * 5               # g5x + g92 (translation part when rotation is 0)
        self.cycle = None                  # remembered canned cycle words (dict) while a cycle is modal
        self.cycle_il = None               # initial level of a series of cycles (LinuxCNC cycle_il)
        self.ended = False
        # cutter compensation (pmctl.task.rs274.cutter_comp): the queue of moves whose end may still move
        self.cq = ()
        self.cq_start = None               # where the first queued move starts (program X Y)
        self.cq_end = None                 # LinuxCNC's queue endpoint (program X Y) or None
        self.comp_prog = None              # the last programmed point (program X Y Z)
        self.comp_cur = None               # the tool centre there (program X Y Z)
        self.comp_base = None              # after G40: the programmed point the next move starts from
        self.spline_prev = None            # the last G5's end and second control point (a G5 series)

    def copy(self) -> "State":
        s = State.__new__(State)
        s.__dict__ = self.__dict__.copy()
        return s
