"""The compiled NC core: the loop's tick (pmctl.motion.nc.nc_step with ModelFK) in portable C99.

``ncore.c`` / ``ncore.h`` do the arithmetic of nc.py in the same order on flat, caller-owned
buffers (no allocation per tick; the buffers could as well live in shared memory);
``_ncoremodule.c`` is the CPython binding, built at install time (setup.py). nc.py stays the
readable reference and the test oracle (tests/motion/test_ncore.py runs both on the same inputs).

The core reports why the mode changed as an event code plus its numbers; the reason text is made
here by the same functions nc.py uses, so both implementations stop with the same words.
"""

from __future__ import annotations

import math

import numpy as np

from pmctl.core.compensation import STILL_MM_S
from pmctl.core.config import Machine
from pmctl.core.errors import KinematicsError
from pmctl.core.model_fk import (FK_SINGULAR_TEXT, NC_CONST_LEN, ModelFK, fk_branch_text, fk_constants,
                                 fk_noconv_text)
from pmctl.core.vf import TIE as VF_TIE
from pmctl.motion import nc as _nc
from pmctl.motion.nc import IMPLEMENTATIONS, MODEL_LOST, NCParams, NCState, PythonNC

try:
    from pmctl.motion.ncore import _ncore
except ImportError as e:          # pragma: no cover - a broken install
    raise ImportError(
        "pmctl's compiled NC core (pmctl.motion.ncore._ncore) is not built; reinstall with a C compiler "
        "(pip install -e .), or select the Python NC with nc.implementation = \"python\" in the service "
        f"config ({e})") from None

S_LEN, N_LEN = _ncore.NC_S_LEN, _ncore.NC_N_LEN
_S_ACC, _S_QDOT, _S_P, _S_R = _ncore.NC_S_ACC, _ncore.NC_S_QDOT, _ncore.NC_S_P, _ncore.NC_S_R
_S_TIP, _S_AXIS, _S_PERR, _S_QM, _S_T, _S_EV = (_ncore.NC_S_TIP, _ncore.NC_S_AXIS, _ncore.NC_S_PERR,
                                                _ncore.NC_S_QM, _ncore.NC_S_T, _ncore.NC_S_EV)
_S_CDIR, _S_CBL, _S_COMP = _ncore.NC_S_CDIR, _ncore.NC_S_CBL, _ncore.NC_S_COMP
_S_KTH = _ncore.NC_S_KTH
_S_OFF = _ncore.NC_S_OFF
_N_COUNTS, _N_PULSES, _N_MODE, _N_EVENT, _N_HAS_QM, _N_ITER = (
    _ncore.NC_N_COUNTS, _ncore.NC_N_PULSES, _ncore.NC_N_MODE, _ncore.NC_N_EVENT, _ncore.NC_N_HAS_QM,
    _ncore.NC_N_ITER)


def constants(machine: Machine, params: NCParams | None, model: ModelFK | None = None) -> np.ndarray:
    """The flat constant block of the core (ncore.h, nc_setup's order) from the same numbers the
    Python NC uses (ModelFK's and NCParams' plain-float copies)."""
    c = fk_constants(model or ModelFK(machine))
    if params is None:           # FK only (the sim's gravity strain): no NC limits
        c += [0.0] * NC_CONST_LEN
    else:
        L = params._l
        c += [params.dt] + L.ppm + L.vmax + L.amax + L.adt + L.lower + L.upper
        c += [math.cos(params.theta2_max_rad), params.kv, params.damping, params.sv_threshold,
              params.orient_weight_mm]
        c += [float(x) for x in params.k_theta] + [float(x) for x in params.deflection_per_ue]
        c += [float(params.max_pulses_per_tick), params.ferror_mm, params.min_ferror_mm,
              params.max_path_error_mm, float(bool(params.static_strain_comp)), float(params._kth_on)]
        c += L.leak + list(params._inv_w2) + list(params._acc_lp) + [float(bool(params.deflection_ff)), float(params._kth_modal)]
        c += [params.chain_offset_max_mm, params._off_step]
        c += list(params._rest_band)
    a = np.array(c, float)
    if len(a) != _ncore.NC_C_LEN:
        raise AssertionError(f"ncore constants: {len(a)} values, the core takes {_ncore.NC_C_LEN}")
    if _ncore.NC_REST_FF != _nc.REST_FF_PULSES:
        raise AssertionError(f"ncore NC_REST_FF {_ncore.NC_REST_FF} != nc.REST_FF_PULSES {_nc.REST_FF_PULSES}")
    if _ncore.NC_COMP_STILL != STILL_MM_S:
        raise AssertionError(f"ncore NC_COMP_STILL {_ncore.NC_COMP_STILL} != compensation.STILL_MM_S {STILL_MM_S}")
    if _ncore.NC_VF_TIE != VF_TIE:
        raise AssertionError(f"ncore NC_VF_TIE {_ncore.NC_VF_TIE} != vf.TIE {VF_TIE}")
    return a


def _reason(event: int, ev, params: NCParams) -> str:
    """The reason text of a core event (the words of nc.py)."""
    E = _ncore
    if event == E.NC_EV_ENC_NONFINITE:
        return _nc.encoder_fault_text(int(ev[0]), float(ev[1]))
    if event == E.NC_EV_STRAIN_NONFINITE:
        return _nc.strain_fault_text(int(ev[0]), float(ev[1]))
    if event == E.NC_EV_FERROR:
        return _nc.ferror_text(int(ev[0]), float(ev[1]), float(ev[2]), float(ev[3]))
    if event == E.NC_EV_FK_NOCONV:
        return MODEL_LOST + fk_noconv_text([float(x) for x in ev[:3]], float(ev[3]), int(ev[4]))
    if event == E.NC_EV_FK_BRANCH:
        return MODEL_LOST + fk_branch_text([float(x) for x in ev[:3]])
    if event == E.NC_EV_FK_SINGULAR:
        return MODEL_LOST + FK_SINGULAR_TEXT
    if event == E.NC_EV_SVD:
        return MODEL_LOST + _nc.SVD_TEXT
    if event == E.NC_EV_PATH_ERROR:
        return _nc.path_error_text(float(ev[0]), params)
    if event == E.NC_EV_TILT:
        return _nc.tilt_text(float(ev[0]), params)
    if event == E.NC_EV_SOFT_LIMIT:
        return _nc.soft_limit_text(int(ev[0]), float(ev[1]), float(ev[2]), params._l)
    raise AssertionError(f"unknown ncore event {event}")


class CompiledState:
    """Mutable handle on the core's state buffers, with the attributes the loop reads from an
    NCState (``counts``, ``mode``, ``reason``) and the same mode-change methods, which change the
    buffers in place and return the handle. :meth:`snapshot` copies it out as an NCState."""

    __slots__ = ("s", "n", "counts", "pulses", "qdot", "tip", "axis", "offset", "reason", "mode", "_params")

    def __init__(self, s: np.ndarray, n: np.ndarray, params: NCParams):
        self.s, self.n, self._params = s, n, params
        self.counts = n[_N_COUNTS:_N_COUNTS + 5]       # views: always current
        self.pulses = n[_N_PULSES:_N_PULSES + 5]
        self.qdot = s[_S_QDOT:_S_QDOT + 5]             # joint rates, mm/s (read them; the core writes)
        self.tip = s[_S_TIP:_S_TIP + 3]                # model tool tip and axis in W
        self.axis = s[_S_AXIS:_S_AXIS + 3]
        self.offset = s[_S_OFF:_S_OFF + 3]             # chain-length offset applied, mm
        self.reason = ""
        self.mode = int(n[_N_MODE])            # a copy of n[NC_N_MODE], kept in step by every change

    @property
    def iterations(self) -> int:
        """Newton iterations of the last model FK."""
        return int(self.n[_N_ITER])

    def halted(self, reason):
        self.s[_S_QDOT:_S_QDOT + 5] = 0.0
        self.s[_S_ACC:_S_ACC + 5] = 0.0
        self.n[_N_MODE] = self.mode = _nc.HALTED
        self.reason = reason
        return self

    def stopping(self, reason):
        self.n[_N_MODE] = self.mode = _nc.STOPPING
        self.reason = reason
        return self

    def done(self):
        self.n[_N_MODE] = self.mode = _nc.DONE
        return self

    def uncounted(self, pulses):
        self.counts -= np.asarray(pulses, np.int64)
        return self

    def with_counts(self, counts):
        """The counters set to what a device reports it executed (after a backend fault)."""
        self.counts[:] = np.asarray(counts, np.int64)
        return self

    def load(self, st: NCState):
        s, n = self.s, self.n
        s[:] = 0.0
        n[:] = 0
        n[_N_COUNTS:_N_COUNTS + 5] = st.counts
        n[_N_MODE] = st.mode
        s[_S_ACC:_S_ACC + 5] = st.acc
        s[_S_QDOT:_S_QDOT + 5] = st.qdot
        s[_S_P:_S_P + 3] = st.P
        s[_S_R:_S_R + 9] = np.asarray(st.R, float).ravel()
        s[_S_TIP:_S_TIP + 3] = st.tip
        s[_S_AXIS:_S_AXIS + 3] = st.axis
        s[_S_PERR] = st.path_error
        if st.q_model is not None and st.T is not None:
            s[_S_QM:_S_QM + 5] = st.q_model
            s[_S_T:_S_T + 18] = np.asarray(st.T, float).ravel()
            n[_N_HAS_QM] = 1
        for f, at in (("comp_dir", _S_CDIR), ("comp_bl", _S_CBL), ("comp", _S_COMP)):
            v = getattr(st, f, None)
            if v is not None:
                s[at:at + 5] = v
        if st.kth is not None:
            s[_S_KTH:_S_KTH + 12] = st.kth
        if st.offset is not None:
            s[_S_OFF:_S_OFF + 3] = st.offset
        self.reason = st.reason
        self.mode = int(st.mode)
        return self

    def snapshot(self) -> NCState:
        s, n = self.s, self.n
        has = bool(n[_N_HAS_QM])
        comp = ((s[_S_CDIR:_S_CDIR + 5].copy(), s[_S_CBL:_S_CBL + 5].copy(), s[_S_COMP:_S_COMP + 5].copy())
                if self._params.compensation is not None else (None, None, None))
        return NCState(n[_N_COUNTS:_N_COUNTS + 5].copy(), s[_S_ACC:_S_ACC + 5].copy(),
                       s[_S_QDOT:_S_QDOT + 5].copy(), s[_S_P:_S_P + 3].copy(), s[_S_R:_S_R + 9].reshape(3, 3).copy(),
                       s[_S_TIP:_S_TIP + 3].copy(), s[_S_AXIS:_S_AXIS + 3].copy(), int(n[_N_MODE]), self.reason,
                       float(s[_S_PERR]), s[_S_QM:_S_QM + 5].copy() if has else None,
                       s[_S_T:_S_T + 18].reshape(6, 3).copy() if has else None, *comp,
                       s[_S_KTH:_S_KTH + 12].copy() if self._params._kth_modal and has else None,
                       s[_S_OFF:_S_OFF + 3].copy())


class CompiledNC:
    """The loop's NC in C, with the interface of nc.PythonNC: ``load(state)`` -> a
    :class:`CompiledState` on preallocated buffers; ``step(state, target, feedback)`` ->
    (pulses, state). The pulses are a view of the state buffer, valid until the next step (copy
    them to keep them)."""

    implementation = "compiled"

    def __init__(self, machine: Machine, params: NCParams, s: np.ndarray | None = None,
                 n: np.ndarray | None = None):
        self.params = params
        self.s = np.zeros(S_LEN) if s is None else s
        self.n = np.zeros(N_LEN, np.int64) if n is None else n
        # the flat compensation table (pmctl.core.compensation), kept here: the core reads it every tick
        self.comp = None if params.compensation is None else params.compensation.flat()
        self.core = _ncore.Core(constants(machine, params), self.s, self.n, self.comp)
        self.handle = CompiledState(self.s, self.n, params)
        self._step = self.core.step
        self._ev = self.s[_S_EV:_S_EV + 6]

    def load(self, state: NCState) -> CompiledState:
        return self.handle.load(state)

    def step(self, state: CompiledState, target, feedback, offset=None):
        if offset is not None and not isinstance(offset, np.ndarray):
            offset = np.asarray(offset, float)
        r = self._step(target, feedback.enc, feedback.strain, offset)      # 16 * event + mode
        state.mode = r & 15
        if r >= 16:
            state.reason = _reason(r >> 4, self._ev, self.params)
        return state.pulses, state


class CompiledFK:
    """ModelFK's per-tick path in C (the sim plant's load-side pose and gravity strain):
    ``solve(q)`` Newton from the last pose with the predictor, ``static_strain()`` of that pose."""

    def __init__(self, machine: Machine, P, R, q):
        self.core = _ncore.Core(constants(machine, None), np.zeros(S_LEN), np.zeros(N_LEN, np.int64))
        self.P = np.array(P, float).ravel().copy()
        self.R = np.array(R, float).ravel().copy()
        self.q = np.array(q, float).copy()
        self.T = np.zeros(18)
        self.has_T = False
        self.dL = np.zeros(3)
        self._tip, self._axis, self._J, self._T1 = np.zeros(3), np.zeros(3), np.zeros(30), np.zeros(18)
        self._ev = np.zeros(6)
        self.strain = np.zeros(3)

    def solve(self, q) -> int:
        """Model pose at joints q (5,); returns the Newton iterations (raises KinematicsError)."""
        q = np.ascontiguousarray(q, float)
        if self.has_T:
            np.subtract(q[:3], self.q[:3], out=self.dL)
            r = self.core.fk(q, self.P, self.R, self.dL, self.T, self._tip, self._axis, self._J, self._T1, self._ev)
        else:
            r = self.core.fk(q, self.P, self.R, None, None, self._tip, self._axis, self._J, self._T1, self._ev)
        if r < 0:
            raise KinematicsError(_reason(-r, self._ev, None)[len(MODEL_LOST):])
        self.T[:] = self._T1
        self.has_T = True
        self.q[:] = q
        return r

    def static_strain(self) -> np.ndarray:
        self.core.static_strain(self.R, self.T, self.strain)
        return self.strain


def make_nc(machine: Machine, params: NCParams, implementation: str | None = None):
    """The NC the loop runs: ``implementation`` (default ``params.implementation``) "compiled" ->
    :class:`CompiledNC`, "python" -> pmctl.motion.nc.PythonNC (the reference)."""
    impl = implementation or params.implementation
    if impl == "python":
        return PythonNC(machine, params)
    if impl == "compiled":
        return CompiledNC(machine, params)
    raise ValueError(f"NC implementation must be one of {', '.join(IMPLEMENTATIONS)}, got {impl!r}")
