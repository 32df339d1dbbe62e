"""Service configs for tests that start `pmctl run` or `pmctl serve` (one writer for the whole
suite). Every config the tests write has a generous stall limit and overrun allowance (the suite
runs on busy machines, and a slow tick must not be what stops these runs) and no state file."""

from pathlib import Path


def service_toml(where, rate=1000, *, kv=None, k_theta=None, flex=None, sim="", nc="", extra="",
                 realtime=None, stall_ms=5000, name="service.toml") -> Path:
    """Write a service config for the simulated backend and return its path.

    where: a folder (the file is `name` in it) or a path ending in .toml. kv, k_theta: the NC's
    gains ([nc]); nc: more [nc] lines; flex: the simulated plant's flexible chains; sim: more
    [hal.sim] lines; extra: TOML appended after everything (more sections, or keys of [hal.sim]
    when no section header starts it)."""
    p = Path(where)
    if p.suffix != ".toml":
        p = p / name
    loop = f"[loop]\nrate_hz = {rate}\nstall_timeout_ms = {stall_ms}\nmax_overruns_in_row = 100000\nstate_file = \"\"\n"
    if realtime is not None:
        loop += f"realtime = {str(bool(realtime)).lower()}\n"
    nc_lines = (f"kv_per_s = {kv}\n" if kv is not None else "") + \
               (f"k_theta_per_s = {k_theta}\n" if k_theta is not None else "") + nc
    text = loop + (f"[nc]\n{nc_lines}" if nc_lines else "") + '[hal]\nbackend = "sim"\n'
    sim_lines = (f"flex = {str(bool(flex)).lower()}\n" if flex is not None else "") + sim
    if sim_lines:
        text += "[hal.sim]\n" + sim_lines + ("" if sim_lines.endswith("\n") else "\n")
    p.write_text(text + extra)
    return p


def sim_service(where, rate=1000, extra="", kv=400, k_theta=200) -> Path:
    """The tests' usual machine: flexible simulated chains, kv 400/s, K_theta 200/s."""
    return service_toml(where, rate, kv=kv, k_theta=k_theta, flex=True, extra=extra)
