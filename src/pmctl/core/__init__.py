"""The machine model: configuration, kinematics, statics, V-F laws, recordings. Pure functions of
their inputs; no I/O beyond reading and writing files that are named to them."""
