"""Parameters of RS-274/NGC, as LinuxCNC keeps them.

- **Numbered** ``#1`` .. ``#5602``: 0 until set. ``#1``-``#30`` are a subroutine's arguments (local
  to each call: the caller's values come back on return); ``#31``-``#5000`` are free.
- **Named local** ``#<name>``: local to the subroutine call (or the main program) that sets it.
- **Named global** ``#<_name>`` (a leading underscore): one value for the whole program.
- **System parameters** (numbered, in mm and degrees whatever G20/G21 says, as LinuxCNC keeps them in
  machine units): ``#5061``-``#5069`` the last probe position, ``#5070`` its success; ``#5161``-``#5169``
  the G28 position, ``#5181``-``#5189`` the G30 position (machine coordinates); ``#5210`` G92 on,
  ``#5211``-``#5219`` the G92 offsets; ``#5220`` the coordinate system (1 = G54 .. 9 = G59.3);
  ``#5221``-``#5230`` G54's X Y Z A B C U V W and XY rotation R, then 20 per system up to
  ``#5381``-``#5390`` (G59.3); ``#5399`` the result of M66; ``#5400`` the tool in the spindle,
  ``#5401``-``#5409`` its offsets, ``#5410`` its diameter, ``#5411``-``#5413`` its lathe angles and
  orientation (read only); ``#5420``-``#5428`` the current position in the active coordinate system
  and program units (read only). C U V W slots exist for LinuxCNC's numbering; this machine has no
  such axes, so they stay 0.
- **Predefined named** (read only, computed on reading): ``#<_x>`` ... ``#<_b>`` (like #5420..),
  ``#<_metric>``, ``#<_imperial>``, ``#<_absolute>``, ``#<_incremental>``, ``#<_inverse_time>``,
  ``#<_units_per_minute>``, ``#<_units_per_rev>``, ``#<_coord_system>`` (540 .. 593),
  ``#<_tool_offset>``, ``#<_plane>`` (170 180 190), ``#<_motion_mode>`` (G code x 10), ``#<_ccomp>``,
  ``#<_retract_r_plane>``, ``#<_retract_old_z>``, ``#<_ijk_absolute_mode>``, ``#<_spindle_on>``,
  ``#<_spindle_cw>``, ``#<_mist>``, ``#<_flood>``, ``#<_feed>``, ``#<_rpm>``, ``#<_current_tool>``,
  ``#<_selected_tool>``, ``#<_value>`` and ``#<_value_returned>`` (the last subroutine's return
  value), ``#<_call_level>``, ``#<_line>``, ``#<_vmajor>``, ``#<_vminor>``.

Reading a named parameter that was never set is an error, as in LinuxCNC (``EXISTS`` asks first).
"""

from __future__ import annotations

from pmctl.task.rs274.expressions import MAX_PARAMETER, EvalError, value

class Unsupported(EvalError):
    """A parameter pmctl cannot have (a LinuxCNC configuration's HAL pin or INI value)."""

    kind = "unsupported"


SUB_PARAMS = 30                     # #1..#30: a subroutine's arguments, local to each call
READ_ONLY = set(range(5400, 5414)) | set(range(5420, 5429))
G28_BASE, G30_BASE = 5161, 5181
G92_FLAG, G92_BASE = 5210, 5211
CS_PARAM = 5220
CS_BASE, CS_STRIDE = 5221, 20        # G54 X at 5221, G55 X at 5241, ... G59.3 X at 5381; +9 = R
PROBE_BASE, PROBE_OK = 5061, 5070
M66_RESULT = 5399
TOOL_BASE = 5400
POS_BASE = 5420
AXIS_SLOT = {"x": 0, "y": 1, "z": 2, "a": 3, "b": 4, "c": 5, "u": 6, "v": 7, "w": 8}


class Parameters:
    """The parameter store. ``dynamic``: read-only values computed on reading, name -> callable()
    for named ones and number -> callable() for #5420-#5428. Evaluation context for
    pmctl.task.rs274.expressions (``param``, ``exists``)."""

    def __init__(self):
        self.numbered = [0.0] * (MAX_PARAMETER + 1)
        self.globals: dict = {}
        self.frames: list = [{}]          # named locals, one dict per call level (0: the main program)
        self.dynamic: dict = {}           # "_x" -> callable, 5420 -> callable
        self.column = None                # the column of the word being evaluated (for errors)

    # ---- reading
    def param(self, ref):
        if ref.__class__ is int:
            f = self.dynamic.get(ref)
            return f() if f is not None else self.numbered[ref]
        if ref.__class__ is str:
            return self.named(ref)
        n = value(ref[1], self)                   # ("#", tree): #[expr]
        k = round(n)
        if abs(n - k) > 1e-4 or not 1 <= k <= MAX_PARAMETER:
            raise EvalError(f"parameter number {n:g} is not an integer within 1 .. {MAX_PARAMETER}", self.column)
        return self.param(int(k))

    def named(self, name):
        if name.startswith("_"):
            f = self.dynamic.get(name)
            if f is not None:
                return f()
            v = self.globals.get(name)
        else:
            v = self.frames[-1].get(name)
        if v is None and (name.startswith("_hal[") or name.startswith("_ini[")):
            raise Unsupported(f"#<{name}> reads a {'HAL pin' if name.startswith('_hal[') else 'INI setting'} of a "
                              "LinuxCNC configuration, which pmctl has not: give the value in the program",
                              self.column)
        if v is None:
            raise EvalError(f"named parameter #<{name}> is not defined (set it first, or test with "
                            f"EXISTS[#<{name}>])", self.column)
        return v

    def exists(self, name):
        if name.startswith("_"):
            return name in self.dynamic or name in self.globals
        return name in self.frames[-1]

    # ---- writing
    def number_of(self, ref):
        """The parameter number of an assignment target (int or ('#', tree))."""
        if ref.__class__ is int:
            return ref
        n = value(ref[1], self)
        k = round(n)
        if abs(n - k) > 1e-4 or not 1 <= k <= MAX_PARAMETER:
            raise EvalError(f"parameter number {n:g} is not an integer within 1 .. {MAX_PARAMETER}", self.column)
        return int(k)

    def set(self, ref, v, undo=None):
        """Set a parameter (``ref``: int or name). ``undo``: a list that gets (ref, old value or None)."""
        if ref.__class__ is int:
            if ref in READ_ONLY:
                raise EvalError(f"parameter #{ref} is read only ({describe(ref)})", self.column)
            if undo is not None:
                undo.append((ref, self.numbered[ref]))
            self.numbered[ref] = v
            return
        if name_is_read_only(ref, self):
            raise EvalError(f"parameter #<{ref}> is read only (a predefined parameter)", self.column)
        d = self.globals if ref.startswith("_") else self.frames[-1]
        if undo is not None:
            undo.append((ref, d.get(ref)))
        d[ref] = v

    def restore(self, undo):
        for ref, old in reversed(undo):
            if ref.__class__ is int:
                self.numbered[ref] = old
            else:
                d = self.globals if ref.startswith("_") else self.frames[-1]
                if old is None:
                    d.pop(ref, None)
                else:
                    d[ref] = old

    # ---- subroutine calls
    def push_call(self, args):
        """Enter a subroutine: #1..#30 become the arguments (0 beyond them), new named locals.
        Returns what pop_call needs."""
        saved = self.numbered[1:SUB_PARAMS + 1]
        vals = list(args)[:SUB_PARAMS] + [0.0] * (SUB_PARAMS - min(len(args), SUB_PARAMS))
        self.numbered[1:SUB_PARAMS + 1] = vals
        self.frames.append({})
        return saved

    def pop_call(self, saved):
        self.numbered[1:SUB_PARAMS + 1] = saved
        if len(self.frames) > 1:
            self.frames.pop()

    def set_return(self, v):
        if v is None:  # LinuxCNC (interp_read.cc): a bare return or endsub sets both to 0
            self.globals["_value"] = 0.0
            self.globals["_value_returned"] = 0.0
        else:
            self.globals["_value"] = float(v)
            self.globals["_value_returned"] = 1.0


def name_is_read_only(name, params):
    return name in params.dynamic


def describe(n: int) -> str:
    if 5400 <= n <= 5413:
        return "the tool in the spindle and its offsets"
    if 5420 <= n <= 5428:
        return "the current position"
    return "a system parameter"


def coordinate_base(system: int) -> int:
    """The parameter of X of coordinate system ``system`` (1 = G54 .. 9 = G59.3)."""
    return CS_BASE + CS_STRIDE * (system - 1)
