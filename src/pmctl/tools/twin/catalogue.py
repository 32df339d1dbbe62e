"""Names and defaults the twin tools share with their command line, importable without numpy."""

# The effects the diagnosis knows and synth can hide (docs/diagnosis-report.md, "Effects").
EFFECTS = ("geometry", "backlash", "pitch_error", "thermal_growth", "compliance", "servo_lag",
           "resonance", "lost_steps", "sensor_gain", "sensor_offset",
           "friction", "periodic_error", "sensor_latency", "forced_vibration", "sensor_drift")
# Physics outside the diagnosis catalogue (blind honesty tests): synth's answer key lists them under
# "oddities", never under "effects"; a diagnosis must locate them as unexplained, not name them.
ODDITIES = ("straightness", "chatter_burst", "reversal_spike", "crash_step", "encoder_glitch", "table_sag",
            "pulse_train")
# Trajectory kinds of synth's runs.
RUNS = ("raster", "circle", "calibration", "warmup")
# Analysis samples per channel in a diagnosis.
DEFAULT_CAP = 10000
