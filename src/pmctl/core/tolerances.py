"""Input tolerances shared by every way a pose comes in (CL data, G-code, ``pmctl kin``), in one
place and importable without numpy (the command line prints them in its help)."""

# A tool axis must be a unit vector: |v| within AXIS_TOL of 1 is normalised, anything further off is
# refused. 1e-3 accepts vectors rounded to 3 decimals (worst case |v| - 1 ~ 0.9e-3) and nothing
# that is plainly not a unit vector.
AXIS_TOL = 1e-3
