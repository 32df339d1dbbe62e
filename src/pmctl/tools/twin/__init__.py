"""Digital twin: recordings, the nominal twin, effect models, diagnosis."""
