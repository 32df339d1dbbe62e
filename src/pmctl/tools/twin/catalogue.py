"""Names and defaults the twin tools share with their command line, importable without numpy."""

# The effects the diagnosis knows and synth can hide (docs/diagnosis-report.md, "Effects").
EFFECTS = ("geometry", "backlash", "pitch_error", "thermal_growth", "compliance", "servo_lag",
           "resonance", "lost_steps", "sensor_gain", "sensor_offset")
# Trajectory kinds of synth's runs.
RUNS = ("raster", "circle", "calibration", "warmup")
# Analysis samples per channel in a diagnosis.
DEFAULT_CAP = 10000
