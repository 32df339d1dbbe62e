"""The alarm codes the controller raises, as grbl numbers them (grbl 1.1; 10, 11 and 17 as grblHAL
does): the supervisor raises them, the Grbl console reports them (``ALARM:n``), homing and the
daemon name them."""

ALARM_HARD_LIMIT, ALARM_SOFT_LIMIT, ALARM_ABORT, ALARM_HOMING_RESET = 1, 2, 3, 6
ALARM_HOMING_PULLOFF, ALARM_HOMING_APPROACH, ALARM_ESTOP, ALARM_HOMING_REQUIRED, ALARM_MOTOR_FAULT = 8, 9, 10, 11, 17
ALARM_PROBE_FAIL_CONTACT = 5      # G38.2 ended without contact
