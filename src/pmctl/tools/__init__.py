"""Tools: off-line work on the machine model and on recordings (digital twin, analyses)."""
