"""Motion: the real-time side (LinuxCNC's motion controller). The fixed-rate loop, the NC step
(Python reference and compiled core), and the pulse-counter state it persists."""
