"""Resonance measurement from the plate-link strain gauges (like a 3-D printer's accelerometer shaper
calibration, but with the gauges the machine already has), and what to do about the modes found.

    pmctl analyze resonance --make-job OUT.ngc [--axis z] [--strokes 4] [--stroke-mm 1] [--dwell-s 0.5]
    pmctl run --job OUT.ngc --record REC ...          # the test move, recorded (strain_1..3, cmd_L1..3)
    pmctl analyze resonance REC [--out DIR]          # PSD per chain, modes, shaper and K_theta advice, PNG

**Test move.** An *impulse* job: short strokes at the top feed with sharp reversals, each followed by
a dwell; every stop rings the chain modes and the dwell records their free decay. G91 (incremental),
so it runs from wherever the tool is.

**Analysis** (per chain i = 1..3, on strain_i with its slow part -- gravity, moving with the pose --
removed by a zero-phase 2.5 Hz high-pass):
- the modes' frequencies and damping ratios from an ARX fit of the gauge's strain to the chain's
  motor-side length (encoders, else the pulse counters) over the whole recording (:func:`arx_modes`):
  the gauge's input is known, so every motion is excitation (free-decay fits of the dwells were
  spoilt by the pose loop's one-pulse dithering at rest, before the NC's rest deadband);
- the PSD of the first 0.2 s of each dwell, per chain, for the figure (its peak is printed too);
- shapers (pmctl.core.shaper) designed at the mode: residual vibration at the mode and the worst
  within +-10 % (drift, mistuning), the time each stop costs (the shaper's duration) and the corner
  it would cut if applied to the Cartesian targets at 50 mm/s (time-law shaping cuts none);
  the recommendation is the shortest shaper whose worst residual within +-10 % is <= 5 %;
- K_theta for the mode: what ``k_theta_per_s = "auto"`` designs for it
  (pmctl.core.strain_loop.design_k_theta: gain, law, leak, the least damping with the mode 20 % off
  and the sampled loop's gain and phase margins; docs/vibration.md), and the shaper ``--shaper
  auto`` takes (pmctl.core.shaper.recommend);
- ``--write SERVICE.toml``: the modes into that service config's ``[nc]`` (mode_hz,
  mode_damping_ratio, modal_stiffness_N_per_mm from the fit's static gain), where ``pmctl run
  --k-theta auto --shaper auto`` takes them from.
"""

from __future__ import annotations

import json
import math
import os
import tempfile
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from scipy.signal import butter, find_peaks, sosfilt, sosfiltfilt

from pmctl.core import shaper as S
from pmctl.core.errors import InputError, PmctlError
from pmctl.core.recording import read_recording
from pmctl.core.strain_loop import closed_loop_poles, design_k_theta, least_damped_oscillation
from pmctl.motion.service_config import load_service_config

DRIFT = 0.10            # frequency tolerance the recommendation must cover
MAX_REMAINING = 0.05    # residual vibration allowed within the tolerance


# ---------------------------------------------------------------------------------------------
# The test move
# ---------------------------------------------------------------------------------------------

def make_impulse_job(axis: str = "z", strokes: int = 4, stroke_mm: float = 1.0, dwell_s: float = 0.5,
                     feed_mm_min: float = 3000.0) -> str:
    """G-code of the impulse test move: ``strokes`` back-and-forth strokes of ``stroke_mm`` along
    ``axis`` (x, y or z), incremental (G91), each end followed by a ``dwell_s`` dwell."""
    ax = str(axis).upper()
    if ax not in ("X", "Y", "Z"):
        raise InputError("--axis", None, f"must be x, y or z, got {axis!r}")
    if not (strokes >= 1 and 0 < stroke_mm <= 20 and 0.05 <= dwell_s <= 10 and 0 < feed_mm_min <= 6000):
        raise InputError("impulse job", None, "needs strokes >= 1, 0 < stroke <= 20 mm, dwell 0.05..10 s, "
                         "0 < feed <= 6000 mm/min")
    lines = [f"(pmctl resonance test: {strokes} strokes of {stroke_mm:g} mm along {ax} at F{feed_mm_min:g}, "
             f"{dwell_s:g} s dwells for the free decay; incremental, runs from where the tool is)",
             "G21 G91 G17", f"G4 P{dwell_s:g}"]
    for i in range(strokes):
        lines += [f"G1 {ax}{-stroke_mm:g} F{feed_mm_min:g}", f"G4 P{dwell_s:g}",
                  f"G1 {ax}{stroke_mm:g}", f"G4 P{dwell_s:g}"]
    lines.append("G90")
    return "\n".join(lines) + "\n"


# ---------------------------------------------------------------------------------------------
# Spectra and modes
# ---------------------------------------------------------------------------------------------

def dynamic_part(x, fs: float, cutoff_hz: float = 2.5):
    """x through a zero-phase 2nd-order high-pass at ``cutoff_hz`` (removes the gravity strain, which
    follows the pose slowly; flat above a few times the cut-off, so the peaks are not moved)."""
    x = np.asarray(x, float)
    sos = butter(2, cutoff_hz, "highpass", fs=fs, output="sos")
    return sosfiltfilt(sos, x - x[0])


def strain_psd(strain, fs: float, segments=None, nfft: int = 4096):
    """PSD of each chain's dynamic strain, (freqs (F,), psd (C, F)) in µε²/Hz: the average of the
    Hann-windowed periodograms of ``segments`` ((start, end) rows: the free decays of the dwells, so
    the forced response of the strokes does not hide the modes), zero-padded to ``nfft`` points;
    the whole recording as one segment when none is given."""
    s = np.asarray(strain, float)
    if s.ndim == 1:
        s = s[:, None]
    d = np.stack([dynamic_part(s[:, i], fs) for i in range(s.shape[1])])
    segments = segments or [(0, d.shape[1])]
    n = max(nfft, max(b - a for a, b in segments))
    acc = 0.0
    for a, b in segments:
        x = d[:, a:b] - d[:, a:b].mean(1, keepdims=True)
        win = np.hanning(b - a)
        X = np.fft.rfft(x * win, n=n)
        acc = acc + np.abs(X) ** 2 / (fs * np.sum(win ** 2))
    p = 2.0 * acc / len(segments)
    return np.fft.rfftfreq(n, 1.0 / fs), p


def find_peaks_hz(freqs, psd, fmin: float, fmax: float, max_modes: int = 3, rel_prominence: float = 0.05):
    """Frequencies of the most prominent peaks of one PSD within [fmin, fmax], strongest first."""
    sel = (freqs >= fmin) & (freqs <= fmax)
    if sel.sum() < 3:
        return []
    f, p = freqs[sel], psd[sel]
    idx, props = find_peaks(p, prominence=rel_prominence * p.max())
    order = np.argsort(props["prominences"])[::-1][:max_modes]
    out = []
    for i in idx[order]:
        # parabolic interpolation of the peak on a log scale
        if 0 < i < len(p) - 1 and p[i - 1] > 0 and p[i + 1] > 0:
            a, b, c = np.log(p[i - 1]), np.log(p[i]), np.log(p[i + 1])
            den = a - 2 * b + c
            off = 0.5 * (a - c) / den if den != 0 else 0.0
            out.append(float(f[i] + off * (f[1] - f[0])))
        else:
            out.append(float(f[i]))
    return out


def rest_segments(cmd, fs: float, min_s: float = 0.15, still_mm_s: float = 1.0):
    """(start, end) row ranges where the commanded chain lengths move slower than ``still_mm_s``
    (the pose loop's one-pulse corrections are not motion) for >= ``min_s``."""
    c = np.asarray(cmd, float)
    moving = np.any(np.abs(np.diff(c, axis=0)) * fs > still_mm_s, axis=1)
    still = np.r_[~moving, False]
    segs, i, n = [], 0, len(still)
    while i < n:
        if still[i]:
            j = i
            while j < n and still[j]:
                j += 1
            if j - i >= min_s * fs:
                segs.append((i, j))
            i = j
        else:
            i += 1
    return segs


@dataclass
class Mode:
    chain: int                  # 1..3
    freq_hz: float
    damping: float
    psd_peak_hz: float          # strongest peak of the dwells' PSD (for comparison; nan if none)
    fit_rms_ue: float           # RMS of the ARX fit's one-step residual, µε
    strain_per_accel: float = float("nan")   # |static gain| of the fit: µε per mm/s^2 of the chain's
                                             # motor acceleration (= strain gain x modal mass, below the mode)


def arx_gain(u, y, fs: float, n_modes: int = 1) -> float:
    """|Static gain| of the ARX model of :func:`arx_modes`: µε of strain per mm/s^2 of motor
    acceleration, below the modes. For one chain mode that is k_eps x m (the quasi-static stretch
    m a / k times the gauge's k_eps k), so the modal stiffness is that over k_eps, times w^2."""
    return _arx_fit(u, y, fs, n_modes)[2]


def _arx_fit(u, y, fs, n_modes):
    """(AR coefficients, residual RMS, |static gain| per mm/s^2) of the ARX fit of arx_modes."""
    u = np.asarray(u, float)
    y = np.asarray(y, float)
    w2 = np.r_[0.0, 0.0, u[2:] - 2.0 * u[1:-1] + u[:-2]]
    sos = butter(2, 2.5, "highpass", fs=fs, output="sos")
    u = sosfilt(sos, w2)
    y = sosfilt(sos, y - y[0])
    na, nb = 2 * n_modes, 2 * n_modes + 2
    k0 = max(na, nb)
    rows = len(y) - k0
    if rows < 10 * (na + nb):
        raise PmctlError(f"recording too short for the resonance fit ({len(y)} rows)")
    X = np.empty((rows, na + nb))
    for i in range(1, na + 1):
        X[:, i - 1] = y[k0 - i: len(y) - i]
    for j in range(nb):
        X[:, na + j] = u[k0 - j: len(u) - j]
    tgt = y[k0:]
    scale = np.linalg.norm(X, axis=0)
    scale[scale == 0] = 1.0
    theta, *_ = np.linalg.lstsq(X / scale, tgt, rcond=None)
    theta = theta / scale
    res = tgt - X @ theta
    den = 1.0 - float(np.sum(theta[:na]))
    g0 = abs(float(np.sum(theta[na:])) / den) / fs ** 2 if den != 0 else float("nan")   # w2 = a dt^2
    return theta[:na], float(np.sqrt(np.mean(res ** 2))), g0


def arx_modes(u, y, fs: float, n_modes: int = 1, fmin: float = 0.0, fmax: float = float("inf")):
    """Modes of the chain from its known input and measured output: ARX least squares
    y_k = sum_{i=1..2n} a_i y_{k-i} + sum_{j=0..2n+1} b_j w_{k-j}, with w the second difference of
    the motor-side chain length u (the mode answers the motor's acceleration: a constant velocity
    leaves no deflection) and y the gauge strain, both high-passed; the poles of the AR part mapped to continuous time,
    s = ln(z) fs. Unlike an accelerometer, the gauge's input is known (the encoders), so any motion
    -- strokes, stops, pulses at rest -- serves as excitation.
    Returns ([(freq Hz, damping ratio)] sorted by frequency, residual RMS)."""
    a_coef, rms, _ = _arx_fit(u, y, fs, n_modes)
    z = np.roots(np.r_[1.0, -a_coef])
    out = []
    for zi in z:
        if zi.imag <= 0 or abs(zi) >= 1.0:
            continue
        sz = np.log(zi) * fs
        f, zeta = abs(sz) / (2 * math.pi), -sz.real / abs(sz)
        if fmin <= f <= fmax:
            out.append((float(f), float(zeta)))
    return sorted(out), rms


def modes_of_chain(strain_i, u_i, cmd, fs: float, fmin: float, fmax: float, chain: int, n_modes: int = 1,
                   decay_s: float = 0.2):
    """Modes of one chain's gauge (ARX on the whole recording) and the dwells' PSD for the figure."""
    segs = [(a, min(b, a + int(decay_s * fs))) for a, b in rest_segments(cmd, fs)]
    freqs, p = strain_psd(np.asarray(strain_i, float), fs, segs)
    peaks = find_peaks_hz(freqs, p[0], fmin, fmax, 1)
    modes, rms = arx_modes(u_i, strain_i, fs, n_modes, fmin, fmax)
    g0 = arx_gain(u_i, strain_i, fs, n_modes) if n_modes == 1 else float("nan")
    pk = peaks[0] if peaks else float("nan")
    return [Mode(chain, f, z, pk, rms, g0) for f, z in modes], (freqs, p[0])


# ---------------------------------------------------------------------------------------------
# What to do: shapers and K_theta
# ---------------------------------------------------------------------------------------------

@dataclass
class ShaperAdvice:
    name: str
    freq_hz: float
    damping: float
    remaining_at_mode: float        # residual vibration fraction at the mode
    remaining_worst: float          # worst within +-DRIFT
    duration_ms: float              # extra time per stop (time-law shaping)
    smoothing_mm: float             # corner cut if applied to the Cartesian targets at 50 mm/s


def shaper_advice(freq_hz: float, damping: float, speed_mm_s: float = 50.0):
    """Every shaper designed at the mode, and the recommended one (see the module docstring)."""
    z = float(damping) if math.isfinite(damping) else 0.05
    z = min(max(z, 0.0), 0.5)
    band = np.linspace(1 - DRIFT, 1 + DRIFT, 81) * freq_hz
    out = []
    for name in S.SHAPERS:
        sh = S.make_shaper(name, freq_hz, z)
        out.append(ShaperAdvice(name, freq_hz, z, float(S.residual_vibration(sh, freq_hz, z)),
                                float(np.max(S.residual_vibration(sh, band, z))), 1e3 * sh.duration,
                                S.smoothing_mm(sh, speed_mm_s)))
    ok = [a for a in out if a.remaining_worst <= MAX_REMAINING]
    best = min(ok, key=lambda a: a.duration_ms) if ok else min(out, key=lambda a: a.remaining_worst)
    return out, best


def predict_continuous(f, kth, kv, zeta=0.0, leak=None):
    """Mode (Hz, damping ratio) of seed eq. 3.1 in pmctl's gains (kv = K_G K_v K_R, K_theta =
    K_theta K_v K_R, 1/s) with the plant damping zeta added. ``leak`` None: nc.py's loop (the pose loop
    pulls the feedback's motion back): s^3 + (kv + K_theta + 2 zeta w) s^2 + (w^2 + 2 zeta w kv) s
    + kv w^2; a number: the decoupled feedback (offset d' = K_theta y - leak d, rate + kv d):
    (s + leak)(s + kv)(s^2 + 2 zeta w s + w^2) + K_theta s^2 (s + leak + kv)."""
    w = 2 * math.pi * f
    plant = np.array([1.0, 2 * zeta * w, w * w])
    if leak is None:
        poly = np.polyadd(np.polymul([1.0, kv], plant), [kth, 0.0, 0.0])
    else:
        poly = np.polyadd(np.polymul(np.polymul([1.0, leak], [1.0, kv]), plant),
                          kth * np.array([1.0, leak + kv, 0.0, 0.0]))
    r = np.roots(poly)
    osc = r[r.imag > 1e-9]
    if len(osc) == 0:
        return float("nan"), 1.0
    c = osc[np.argmin(-osc.real / np.abs(osc))]
    return abs(c) / (2 * math.pi), -c.real / abs(c)


def predict_sampled(f, kth, kv, dt, zeta=0.0, leak=None):
    """The same loop sampled at dt as the NC runs it (pmctl.core.strain_loop: state (x_m, y, y',
    v_prev, d); each tick v = -kv x_m + kv d + K_theta y (deflection read at the tick start; d = 0
    without ``leak``), the motor ramps by v dt (y' jumps by -(v - v_prev), then (y, y') propagate
    exactly), and d += dt (K_theta y - leak d)). Returns the least damped oscillating pole as
    (damped frequency Hz, damping ratio)."""
    return least_damped_oscillation(closed_loop_poles(f, zeta, kth, kv, dt, leak), dt)


# ---------------------------------------------------------------------------------------------
# The whole analysis of a recording
# ---------------------------------------------------------------------------------------------

def analyse(rec, fmin: float = 5.0, fmax: float | None = None, kv: float = 400.0, n_modes: int = 1):
    """Modes per chain, shaper advice and K_theta per chain of a recording (pmctl.core.recording)."""
    fs = rec.sample_rate_hz or 1.0 / float(np.median(np.diff(rec.t)))
    need = [f"strain_{i}" for i in (1, 2, 3)] + [f"cmd_L{i}" for i in (1, 2, 3)]
    miss = [c for c in need if c not in rec]
    if miss:
        raise InputError(rec.path, None, f"the resonance analysis needs the channels {', '.join(miss)} "
                                         f"(record the test move with pmctl run --record)")
    fmax = fmax or 0.45 * fs
    cmd = np.stack([rec[f"cmd_L{i}"] for i in (1, 2, 3)], 1)
    if not np.all(np.isfinite(cmd)):
        raise InputError(rec.path, None, "cmd_L1..3 have missing values")
    if all(f"enc_L{i}" in rec for i in (1, 2, 3)):
        motor = np.stack([rec[f"enc_L{i}"] for i in (1, 2, 3)], 1)
        if not np.all(np.isfinite(motor)):
            motor = cmd
    else:
        motor = cmd
    chains, spectra = [], []
    for i in (1, 2, 3):
        s = np.asarray(rec[f"strain_{i}"], float)
        ok = np.isfinite(s)
        if ok.sum() < 0.9 * len(s):
            raise InputError(rec.path, None, f"strain_{i} is missing in more than 10 % of the rows")
        s = np.where(ok, s, np.interp(np.arange(len(s)), np.nonzero(ok)[0], s[ok]))
        modes, spec = modes_of_chain(s, motor[:, i - 1], cmd, fs, fmin, fmax, i, n_modes)
        chains.append(modes)
        spectra.append(spec)
    result = {"sample_rate_hz": fs, "chains": []}
    for i, modes in enumerate(chains, 1):
        entry = {"chain": i, "modes": [asdict(m) for m in modes]}
        if modes:
            m0 = modes[0]
            adv, best = shaper_advice(m0.freq_hz, m0.damping)
            entry["shapers"] = [asdict(a) for a in adv]
            entry["recommended_shaper"] = best.name
            z = m0.damping if math.isfinite(m0.damping) else 0.02
            entry["auto_shaper"] = S.recommend(m0.freq_hz, min(z, 0.9))
            try:
                d = design_k_theta(float(m0.freq_hz), float(z), float(kv), 1.0 / fs)
            except PmctlError as e:
                entry["k_theta"] = {"error": str(e)}
            else:
                entry["k_theta"] = {"k_theta_per_s": d.k_theta, "law": "decoupled" if d.soft else "plain",
                                    "leak_per_s": d.leak, "stretch_lowpass_per_s": d.acc_lp if d.soft else None,
                                    "worst_damping": d.worst_damping, "reached": d.reached,
                                    "gain_margin": d.worst_gain_margin, "phase_margin_deg": d.worst_phase_margin_deg}
        result["chains"].append(entry)
    return result, spectra


def _plot(result, spectra, path: Path, title: str):
    import matplotlib  # lazy: matplotlib (heavy) loads only when a figure is drawn
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # lazy: matplotlib (heavy) loads only when a figure is drawn
    fig, (a1, a2) = plt.subplots(2, 1, figsize=(9, 8))
    for (f, p), ch in zip(spectra, result["chains"]):
        a1.semilogy(f[1:], p[1:], label=f"chain {ch['chain']}")
        for m in ch["modes"]:
            a1.axvline(m["freq_hz"], color="grey", lw=0.6, ls="--")
    a1.set_xlabel("frequency (Hz)")
    a1.set_ylabel("strain PSD in the dwells (µε²/Hz)")
    a1.set_title(title)
    a1.legend()
    ch = next((c for c in result["chains"] if c["modes"]), None)
    if ch:
        m = ch["modes"][0]
        fr = np.linspace(0.5, 1.6, 400) * m["freq_hz"]
        z = ch["shapers"][0]["damping"]
        for name in S.SHAPERS:
            sh = S.make_shaper(name, m["freq_hz"], z)
            a2.plot(fr, 100 * S.residual_vibration(sh, fr, z), label=f"{name} ({1e3 * sh.duration:.0f} ms)")
        a2.axvspan((1 - DRIFT) * m["freq_hz"], (1 + DRIFT) * m["freq_hz"], color="0.9")
        a2.axhline(100 * MAX_REMAINING, color="grey", lw=0.6)
        a2.set_ylim(0, 100)
        a2.set_xlabel("mode frequency (Hz)")
        a2.set_ylabel("remaining vibration (%)")
        a2.set_title(f"shapers at chain {ch['chain']}'s {m['freq_hz']:.1f} Hz, damping {z:.3f} "
                     f"(recommended: {ch['recommended_shaper']})")
        a2.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def modes_entry(result, strain_gain: float) -> dict:
    """The ``[nc]`` keys of a service config for the chain modes found (first mode per chain):
    mode_hz, mode_damping_ratio and, when the fit's static gain is known, modal_stiffness_N_per_mm
    = (µε per mm/s^2) / k_eps x w^2 (the gauge sees k_eps k y, and y = m a / k below the mode)."""
    hz, z, k = [], [], []
    for ch in result["chains"]:
        if not ch["modes"]:
            raise PmctlError(f"chain {ch['chain']}: no mode found; nothing written")
        m = ch["modes"][0]
        w = 2 * math.pi * m["freq_hz"]
        hz.append(round(m["freq_hz"], 3))
        z.append(round(min(max(m["damping"], 0.0), 0.9), 4))
        g = m.get("strain_per_accel", float("nan"))
        k.append(round(g * w * w / strain_gain, 1) if math.isfinite(g) and g > 0 else None)
    out = {"mode_hz": hz, "mode_damping_ratio": z}
    if all(x is not None for x in k):
        out["modal_stiffness_N_per_mm"] = k
    return out


def write_modes(path, entry: dict) -> None:
    """Put ``entry`` (:func:`modes_entry`) into the ``[nc]`` table of the service config ``path``:
    those keys replaced where they are, else added under the table's header; the rest of the file
    (comments included) is kept. The new file is validated whole (load_service_config) before it
    replaces the old one, so a refused value leaves the file as it was."""

    p = Path(path)
    try:
        lines = p.read_text(encoding="utf-8").splitlines()
    except OSError as e:
        raise PmctlError(f"--write {p}: cannot read: {e.strerror or e}") from None
    fmt = lambda v: "[" + ", ".join(f"{x:g}" for x in v) + "]"   # noqa: E731
    new = [f"{k} = {fmt(v)}   # pmctl analyze resonance --write" for k, v in entry.items()]
    out, section, placed = [], None, False
    for ln in lines:
        st = ln.strip()
        if st.startswith("[") and not st.startswith("[["):
            section = st.split("]")[0].strip("[ ")
            out.append(ln)
            if section == "nc":
                out += new
                placed = True
            continue
        if section == "nc" and "=" in st and st.split("=")[0].strip() in entry:
            continue
        out.append(ln)
    if not placed:
        out += ["", "[nc]"] + new
    fd, tmp = tempfile.mkstemp(prefix=p.name + ".", suffix=".tmp", dir=str(p.parent))
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write("\n".join(out) + "\n")
        load_service_config(tmp)
        os.replace(tmp, p)
    except BaseException:
        os.unlink(tmp)
        raise


def cmd_resonance(args):
    if args.make_job:
        text = make_impulse_job(args.axis, args.strokes, args.stroke_mm, args.dwell_s, args.feed)
        try:
            Path(args.make_job).write_text(text, encoding="utf-8")
        except OSError as e:
            raise PmctlError(f"--make-job {args.make_job}: cannot write: {e.strerror or e}") from None
        print(f"wrote {args.make_job}: record it with  pmctl run --job {args.make_job} --record DIR  "
              f"then  pmctl analyze resonance DIR")
        return 0
    if not args.recording:
        raise PmctlError("pmctl analyze resonance: give a RECORDING folder, or --make-job OUT.ngc for the test move")
    if Path(args.recording).is_file():          # a Klipper accelerometer CSV (raw or PSD)
        return cmd_accel(args, args.recording)
    rec = read_recording(args.recording)
    if not hasattr(rec.machine, "geometry"):     # a recording of independent axes: its accelerometers
        return cmd_accel(args, rec)
    result, spectra = analyse(rec, args.fmin, args.fmax, args.kv, args.modes)
    out = Path(args.out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise PmctlError(f"--out {out}: cannot create the folder: {e.strerror or e}") from None
    print(f"{rec.name}: {rec.n} rows at {result['sample_rate_hz']:g} Hz")
    for ch in result["chains"]:
        if not ch["modes"]:
            print(f"chain {ch['chain']}: no mode found")
            continue
        for m in ch["modes"]:
            print(f"chain {ch['chain']}: mode {m['freq_hz']:.2f} Hz, damping ratio {m['damping']:.4f} "
                  f"(fit residual {m['fit_rms_ue']:.3g} µε RMS; dwells' PSD peak {m['psd_peak_hz']:.1f} Hz)")
        print(f"  {'shaper':9s} {'at mode':>8s} {'worst +-10%':>12s} {'time/stop':>10s} {'Cartesian smoothing':>20s}")
        for a in ch["shapers"]:
            mark = "  <- recommended" if a["name"] == ch["recommended_shaper"] else ""
            print(f"  {a['name']:9s} {100 * a['remaining_at_mode']:7.2f}% {100 * a['remaining_worst']:11.2f}% "
                  f"{a['duration_ms']:8.1f} ms {1e3 * a['smoothing_mm']:15.1f} um at 50 mm/s{mark}")
        print(f"  --shaper auto: {ch['auto_shaper']}")
        k = ch["k_theta"]
        if "error" in k:
            print(f"  K_theta auto: {k['error']}")
        else:
            law = (f"decoupled, leak {k['leak_per_s']:.1f}/s, stretch low-pass {k['stretch_lowpass_per_s']:.0f}/s"
                   if k["law"] == "decoupled" else "plain")
            print(f"  K_theta auto for this mode: {k['k_theta_per_s']:.0f}/s ({law}); least damping "
                  f"{k['worst_damping']:.2f} with the mode 20 % off, margins: gain x{k['gain_margin']:.1f}, "
                  f"phase {k['phase_margin_deg']:.0f} deg (docs/vibration.md)")
    png = out / "resonance.png"
    _plot(result, spectra, png, f"{rec.name}: strain-gauge PSD per chain")
    js = out / "resonance.json"
    js.write_text(json.dumps(result, indent=1), encoding="utf-8")
    print(f"wrote {png}\nwrote {js}")
    if getattr(args, "write", None):
        entry = modes_entry(result, rec.machine.strain_gain)
        write_modes(args.write, entry)
        print(f"wrote [nc] {', '.join(f'{k} = {v}' for k, v in entry.items())} into {args.write} "
              f"(pmctl run --service {args.write} --k-theta auto --shaper auto uses them)")
    return 0


# ---------------------------------------------------------------------------------------------
# Accelerometers, the way 3-D printers (Klipper) tune their input shapers
# ---------------------------------------------------------------------------------------------
#
# An accelerometer on the toolhead, the machine shaken through a sweep of frequencies: the power
# spectral density of what it measured says where the structure resonates, and each shaper is
# scored by how much of that vibration it would leave and how much it would smooth the path. The
# steps and numbers are those Klipper's calibrate_shaper uses (its documentation and source,
# reimplemented here): Welch PSD with 0.5 s Kaiser windows, the PSD divided by the frequency (the
# sweep's acceleration grows with it), the vibration that a shaper leaves pessimised over damping
# ratios 0.075, 0.1 and 0.15 and counted above 1/20 of the peak (a shaper reduces no more than
# that), shapers designed at damping 0.1, a score smoothing x (v^1.5 + 0.2 v + 0.01). The shapers
# themselves are pmctl's (pmctl.core.shaper: Singhose's closed forms); Klipper's MZV, EI and
# multi-hump EI use its own fitted coefficients, which shifts their best frequencies a little.

ACC_WINDOW_S = 0.5
ACC_MIN_HZ = 5.0
ACC_MAX_HZ = 200.0
MAX_SHAPER_HZ = 150.0
TEST_DAMPING = (0.075, 0.1, 0.15)
VIBRATION_REDUCTION = 20.0
SHAPER_DAMPING = 0.1
SHAPER_MIN_HZ = {"ZV": 21.0, "MZV": 23.0, "EI": 29.0, "2HUMP_EI": 39.0, "3HUMP_EI": 48.0}


def read_accel_csv(path):
    """A Klipper accelerometer CSV: raw samples ``#time,accel_x,accel_y,accel_z`` (mm/s²) ->
    ("raw", {"t", "x", "y", "z"}), or a resonance PSD ``freq,psd_x,psd_y,psd_z,psd_xyz[,...]`` ->
    ("psd", {"freq", "x", "y", "z", "sum", "normalized"}) (``normalized``: the file carries Klipper's
    fitted shapers, so its PSD is already divided by the frequency). InputError naming the file and
    line for anything else."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(p, None, f"cannot read: {getattr(e, 'strerror', None) or e}") from None
    lines = text.splitlines()
    hdr_i = next((i for i, ln in enumerate(lines) if ln.strip() and not ln.startswith("##")), None)
    if hdr_i is None:
        raise InputError(p, 1, "empty file")
    header = lines[hdr_i].strip().lstrip("#").strip()
    names = [c.strip() for c in header.split(",")]
    if names[:4] != ["time", "accel_x", "accel_y", "accel_z"] and names[:5] != ["freq", "psd_x", "psd_y", "psd_z", "psd_xyz"]:
        raise InputError(p, hdr_i + 1, "not a Klipper accelerometer CSV: expected the header "
                                       "'#time,accel_x,accel_y,accel_z' (raw samples) or "
                                       "'freq,psd_x,psd_y,psd_z,psd_xyz' (a resonance PSD)")
    rows, first = [], hdr_i + 2
    for k, ln in enumerate(lines[hdr_i + 1:], first):
        s = ln.strip()
        if not s or s.startswith("#"):
            continue
        cells = s.split(",")
        try:
            vals = [float(c) if c.strip() else math.nan for c in cells]
        except ValueError:
            bad = next(c for c in cells if c.strip() and not _is_float(c))
            raise InputError(p, k, f"{bad.strip()!r} is not a number") from None
        if len(vals) < min(len(names), 4):
            raise InputError(p, k, f"row has {len(vals)} cells, the header has {len(names)}")
        rows.append(vals[:len(names)] + [math.nan] * (len(names) - len(vals)))
    if len(rows) < 8:
        raise InputError(p, first, "fewer than 8 rows of data")
    a = np.array(rows, float)
    if names[:4] == ["time", "accel_x", "accel_y", "accel_z"]:
        if not np.all(np.diff(a[:, 0]) > 0):
            r = int(np.argmax(np.diff(a[:, 0]) <= 0)) + 1
            raise InputError(p, first + r, "time is not strictly increasing")
        return "raw", {"t": a[:, 0], "x": a[:, 1], "y": a[:, 2], "z": a[:, 3]}
    a = np.nan_to_num(a)
    return "psd", {"freq": a[:, 0], "x": a[:, 1], "y": a[:, 2], "z": a[:, 3], "sum": a[:, 4],
                   "normalized": "shapers:" in names}


def _is_float(s):
    try:
        float(s)
        return True
    except ValueError:
        return False


def accel_psd(t, acc):
    """Welch PSD ((mm/s²)²/Hz) of one accelerometer axis: windows of ACC_WINDOW_S rounded up to a
    power of two, half overlapping, Kaiser (β 6), each detrended by its mean; the rate is the
    samples over the span (an accelerometer's clock, not the host's stamps)."""
    t, acc = np.asarray(t, float), np.asarray(acc, float)
    fs = (len(t) - 1) / (t[-1] - t[0]) if len(t) > 1 else 1.0
    nfft = 1 << int(fs * ACC_WINDOW_S - 1).bit_length()
    if len(acc) <= nfft:
        raise PmctlError(f"the accelerometer log is too short: {len(acc)} samples, a window needs {nfft}")
    win = np.kaiser(nfft, 6.0)
    step = nfft // 2
    starts = np.arange(0, len(acc) - nfft + 1, step)
    seg = np.stack([acc[s:s + nfft] for s in starts], 1)
    seg = win[:, None] * (seg - seg.mean(0))
    spec = np.abs(np.fft.rfft(seg, axis=0)) ** 2 / (fs * np.sum(win ** 2))
    spec[1:-1] *= 2.0
    return np.fft.rfftfreq(nfft, 1.0 / fs), spec.mean(1)


def normalize_psd(freq, psd):
    """The PSD of a frequency sweep divided by its frequency (the sweep's acceleration amplitude
    grows with it), and the bins below 2·ACC_MIN_HZ faded out (the slow part of the sweep)."""
    freq = np.asarray(freq, float)
    out = np.asarray(psd, float) / (freq + 0.1)
    low = freq < 2 * ACC_MIN_HZ
    out[low] *= np.exp(-(2 * ACC_MIN_HZ / (freq[low] + 0.1)) ** 2 + 1.0)
    return out


def shaper_smoothing(sh, accel=5000.0, scv=5.0) -> float:
    """How far a shaper pulls a corner in (mm) at ``accel`` with the square-corner velocity ``scv``:
    the larger of the offsets of a 90° and a 180° turn, each the impulses' spread about their mean
    time weighted by what they travel (Klipper's measure of smoothing)."""
    A, T = np.asarray(sh.A, float), np.asarray(sh.T, float)
    ts = float(A @ T)
    d = T - ts
    late = d >= 0
    off90 = math.sqrt(2.0) * float(np.sum(A[late] * (scv + 0.5 * accel * d[late]) * d[late]))
    off180 = float(np.sum(A * 0.5 * accel * d * d))
    return max(off90, off180)


def shaper_max_accel(sh, scv=5.0, target=0.12) -> float:
    """The largest acceleration whose smoothing stays within ``target`` mm (bisection)."""
    lo, hi = 0.0, 1.0
    while shaper_smoothing(sh, hi, scv) <= target and hi < 1e9:
        lo, hi = hi, hi * 2
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if shaper_smoothing(sh, mid, scv) <= target else (lo, mid)
    return lo


@dataclass
class ShaperFit:
    name: str
    freq_hz: float
    vibrations: float          # share of the vibration above the threshold that the shaper leaves
    smoothing_mm: float
    score: float
    max_accel: float           # mm/s² that keeps the smoothing within 0.12 mm


def remaining_vibrations(sh, freq, psd) -> float:
    """Share of the PSD above max/VIBRATION_REDUCTION that the shaper leaves, the worst over
    TEST_DAMPING (the structure's damping is unknown)."""
    thr = psd.max() / VIBRATION_REDUCTION
    total = np.maximum(psd - thr, 0.0).sum()
    worst = 0.0
    for z in TEST_DAMPING:
        v = S.residual_vibration(sh, freq, z)
        worst = max(worst, float(np.maximum(v * psd - thr, 0.0).sum() / total) if total > 0 else 0.0)
    return worst


def fit_shapers(freq, psd, scv=5.0, max_freq=ACC_MAX_HZ):
    """Each shaper at its best frequency (0.2 Hz steps from its lowest up to MAX_SHAPER_HZ): the
    frequency that leaves the least vibration, then among those within 10 % (+0.05 %) of it the one
    with the best score; and the recommended one: a shaper replaces the one before it (ZV, MZV, EI,
    2HUMP_EI, 3HUMP_EI) when its score is 20 % better, or 5 % better with 10 % less smoothing.
    Returns (fits, recommended)."""
    freq, psd = np.asarray(freq, float), np.asarray(psd, float)
    keep = freq <= max_freq
    freq, psd = freq[keep], psd[keep]
    fits = []
    for name, fmin in SHAPER_MIN_HZ.items():
        res = []
        for f in np.arange(fmin, MAX_SHAPER_HZ, 0.2)[::-1]:
            sh = S.make_shaper(name, float(f), SHAPER_DAMPING)
            vib = remaining_vibrations(sh, freq, psd)
            sm = shaper_smoothing(sh, scv=scv)
            res.append((float(f), vib, sm, sm * (vib ** 1.5 + 0.2 * vib + 0.01), sh))
        best = min(res, key=lambda r: r[1])
        sel = best
        for r in res[::-1]:
            if r[1] < best[1] * 1.1 + 0.0005 and r[3] < sel[3]:
                sel = r
        fits.append(ShaperFit(name, sel[0], sel[1], sel[2], sel[3], shaper_max_accel(sel[4], scv)))
    rec = None
    for s in fits:
        if rec is None or s.score * 1.2 < rec.score or (s.score * 1.05 < rec.score and s.smoothing_mm * 1.1 < rec.smoothing_mm):
            rec = s
    return fits, rec


def analyse_accel(path_or_rec, axis=None):
    """Klipper's way on an accelerometer CSV or on the acc_* channels of a recording of independent
    axes: (freq, psd per axis and summed, fits, recommended, source)."""
    if isinstance(path_or_rec, (str, Path)) and Path(path_or_rec).is_file():
        kind, d = read_accel_csv(path_or_rec)
        if kind == "raw":
            f, px = accel_psd(d["t"], d["x"])
            _, py = accel_psd(d["t"], d["y"])
            _, pz = accel_psd(d["t"], d["z"])
            psd = {"x": px, "y": py, "z": pz, "sum": px + py + pz}
            psd = {k: normalize_psd(f, v) for k, v in psd.items()}
            src = f"raw accelerometer samples, {len(d['t'])} at {(len(d['t']) - 1) / (d['t'][-1] - d['t'][0]):.0f} Hz"
        else:
            f = d["freq"]
            psd = {k: d[k] for k in ("x", "y", "z", "sum")}
            if not d["normalized"]:
                psd = {k: normalize_psd(f, v) for k, v in psd.items()}
            src = "a resonance PSD"
    else:
        rec = path_or_rec
        chans = [c for c in rec.columns if c.startswith("acc_")]
        if not chans:
            raise InputError(rec.path, None, "no acc_<A> channel: an accelerometer resonance analysis needs one")
        psd = {}
        for c in chans:
            x = np.asarray(rec[c], float)
            ok = np.isfinite(x)
            f, p = accel_psd(rec.t[ok], x[ok])
            psd[c[4:]] = normalize_psd(f, p)
        psd["sum"] = sum(psd[c[4:]] for c in chans)
        src = f"channels {', '.join(chans)} of the recording"
    use = psd["sum"] if axis in (None, "all", "sum") else psd[axis]
    fits, rec = fit_shapers(f, use)
    return f, psd, fits, rec, src


def cmd_accel(args, target) -> int:
    """`pmctl analyze resonance FILE.csv` (or a recording with acc_* channels): PSD, each shaper at
    its best frequency, the recommended one; resonance.png and resonance.json in --out."""
    f, psd, fits, rec, src = analyse_accel(target, getattr(args, "accel_axis", None))
    out = Path(args.out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise PmctlError(f"--out {out}: cannot create the folder: {e.strerror or e}") from None
    use = psd["sum"]
    band = (f >= ACC_MIN_HZ) & (f <= ACC_MAX_HZ)
    peak = float(f[band][np.argmax(use[band])]) if band.any() else float("nan")
    print(f"{Path(str(getattr(target, 'path', target))).name}: {src}; PSD peak at {peak:.1f} Hz")
    for s in fits:
        print(f"  {s.name.lower():9s} {s.freq_hz:6.1f} Hz  vibrations {100 * s.vibrations:5.1f} %  smoothing "
              f"{s.smoothing_mm:.3f} mm  max_accel <= {s.max_accel:.0f} mm/s²")
    print(f"recommended shaper: {rec.name.lower()} @ {rec.freq_hz:.1f} Hz")
    js = out / "resonance.json"
    js.write_text(json.dumps({"source": str(target if isinstance(target, (str, Path)) else target.path),
                              "psd_peak_hz": peak,
                              "shapers": [asdict(s) for s in fits],
                              "recommended": {"shaper": rec.name.lower(), "freq_hz": rec.freq_hz}}, indent=1),
                  encoding="utf-8")
    import matplotlib  # lazy: matplotlib (heavy) loads only when a figure is drawn
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # lazy: matplotlib (heavy) loads only when a figure is drawn
    fig, ax = plt.subplots(figsize=(9, 5))
    m = f <= ACC_MAX_HZ
    for k, v in psd.items():
        ax.plot(f[m], v[m], label=k if k != "sum" else "sum", lw=1.6 if k == "sum" else 0.8)
    ax.set_xlabel("frequency (Hz)")
    ax.set_ylabel("PSD / frequency ((mm/s²)²/Hz per Hz)")
    ax.set_title(f"accelerometer PSD; recommended {rec.name.lower()} @ {rec.freq_hz:.1f} Hz")
    ax.legend(fontsize=8)
    fig.tight_layout()
    png = out / "resonance.png"
    fig.savefig(png, dpi=110)
    plt.close(fig)
    print(f"wrote {png}\nwrote {js}")
    return 0
