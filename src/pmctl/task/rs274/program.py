"""Running a whole program (or a console line) through the interpreter, collecting every problem.

:class:`Interpreter` holds the modal state, the parameters, the tool table and the output between
lines. ``run_program`` walks the file line by line -- block delete, ``%`` framing, O-word flow
(pmctl.task.rs274.flow), blocks (pmctl.task.rs274.execute) -- and keeps going after a problem: the bad
block is skipped with the state it started from, and the problem is kept with its file, line, column,
kind and message. ``run_line`` does one line for the console.

Limits: at most ``MAX_BLOCKS`` blocks are executed (an endless loop is a problem, not a hang), at most
``MAX_CALL_DEPTH`` nested calls, and ``MAX_PROBLEMS`` problems are listed (then one that counts the
rest).
"""

from __future__ import annotations

import gc
import re

import numpy as np

from pmctl.core.errors import Problem
from pmctl.task.job import DWELL, EVENT, Job
from pmctl.task.rs274 import parameters as P
from pmctl.task.rs274.cutter_comp import CutterComp
from pmctl.task.rs274.execute import Config, Executor, Refusal
from pmctl.task.rs274.expressions import EvalError, value
from pmctl.task.rs274.flow import FlowError, Source, SubroutineFiles
from pmctl.task.rs274.modal import State
from pmctl.task.rs274.words import LexError

MAX_BLOCKS = 1_000_000
MAX_CALL_DEPTH = 100
MAX_PROBLEMS = 500
GRBL_QUERIES = {"$", "$$", "$#", "$G", "$I", "$N", "?"}
_SUBST = re.compile(r"#<([^>]*)>|#([0-9]+)")


class _Frame:
    __slots__ = ("src", "ret", "saved", "label", "kind", "repeat", "counters")

    def __init__(self, src, ret, saved, label, kind, repeat=1):
        self.src, self.ret, self.saved, self.label, self.kind, self.repeat = src, ret, saved, label, kind, repeat
        self.counters = {}


class Interpreter:
    """The RS-274 interpreter: state, parameters and output that persist from line to line."""

    def __init__(self, cfg: Config, start_pos, offsets=None):
        self.cfg = cfg
        self.params = P.Parameters()
        for base in (P.G28_BASE, P.G30_BASE):          # G28/G30 go home until G28.1/G30.1 store another place
            for k in range(5):
                self.params.numbered[base + k] = float(cfg.home[k])
        self.moves: list = []
        self.messages: list = []
        self.problems: list = []
        self.n_problems = 0
        self.ex = Executor(cfg, self.params, State(start_pos), self.moves, self.messages)
        self.ex.comp = CutterComp(self.ex)
        if offsets:
            self.load_offsets(offsets)
        self.subfiles = SubroutineFiles(cfg.subroutine_path)
        self.blocks = 0
        self.main_counters = {}          # repeat counters of the main program
        self.labels = {}                 # (file, subroutine, label) -> the line of the structure it names

    # ------------------------------------------------------------------ offsets (the journal's format)
    def load_offsets(self, o):
        """Coordinate systems, G92, G28/G30 from the console journal's ``offsets`` (mm, deg):
        ``{"wcs": {"G54": [x, y, z, a, b], ...}, "g92": [...], "active": "G54", "g28": [...], "g30": [...],
        "rotation": {"G54": deg, ...}}`` (keys beyond ``wcs``/``g92``/``active`` optional)."""
        from pmctl.task.rs274.modal import WCS_NAMES
        num = self.params.numbered
        wcs = o.get("wcs", {}) or {}
        for k, name in enumerate(WCS_NAMES, 1):
            vals = wcs.get(name)
            base = P.coordinate_base(k)
            if vals is not None:
                for i in range(5):
                    num[base + i] = float(vals[i]) if i < len(vals) else 0.0
            rot = (o.get("rotation") or {}).get(name)
            if rot is not None:
                num[base + 9] = float(rot)
        g92 = o.get("g92")
        if g92 is not None:
            for i in range(5):
                num[P.G92_BASE + i] = float(g92[i]) if i < len(g92) else 0.0
            num[P.G92_FLAG] = 1.0 if any(float(x) != 0.0 for x in g92) else 0.0
        for key, base in (("g28", P.G28_BASE), ("g30", P.G30_BASE)):
            vals = o.get(key)
            if vals is not None:
                for i in range(5):
                    num[base + i] = float(vals[i])
        st = self.ex.st
        st.g92 = [num[P.G92_BASE + i] for i in range(5)] if num[P.G92_FLAG] else [0.0] * 5
        active = o.get("active", "G54")
        self.ex.select_cs(st, WCS_NAMES.index(active) + 1 if active in WCS_NAMES else 1)

    def offsets(self) -> dict:
        from pmctl.task.rs274.modal import WCS_NAMES
        num = self.params.numbered
        wcs, rot = {}, {}
        for k, name in enumerate(WCS_NAMES, 1):
            base = P.coordinate_base(k)
            wcs[name] = [num[base + i] for i in range(5)]
            if num[base + 9]:
                rot[name] = num[base + 9]
        out = {"wcs": wcs, "g92": list(self.ex.st.g92), "active": WCS_NAMES[self.ex.st.cs - 1],
               "g28": [num[P.G28_BASE + i] for i in range(5)], "g30": [num[P.G30_BASE + i] for i in range(5)]}
        if rot:
            out["rotation"] = rot
        return out

    # ------------------------------------------------------------------ problems
    def problem(self, file, line, column, kind, message):
        self.n_problems += 1
        if len(self.problems) < MAX_PROBLEMS:
            self.problems.append(Problem(file, line, column, kind, message))
        elif len(self.problems) == MAX_PROBLEMS:
            self.problems.append(Problem(file, line, None, kind, "more problems follow (only the first "
                                                                 f"{MAX_PROBLEMS} are listed)"))

    # ------------------------------------------------------------------ one block
    def block(self, src: Source, i: int, ln, lineno=None):
        """Execute a lexed non-O-word line; returns the executor's result; problems are recorded
        (``lineno``: the line number the moves carry, default i + 1)."""
        ex = self.ex
        ex.line = i + 1 if lineno is None else lineno
        ex.file = src.label
        st = ex.st.copy()
        mark, nmsg = len(self.moves), len(self.messages)
        undo = []
        ex.events = []
        ex.notes = []
        blk = None
        try:
            if ln.comments:
                self.comments(st, ln, i)
            blk = ex.read(ln, i + 1)
            if ln.assigns:
                vals = []
                for target, val, col in ln.assigns:
                    self.params.column = col
                    ref = target if target.__class__ is str else self.params.number_of(target)
                    vals.append((ref, value(val, self.params)))
                for ref, v in vals:
                    self.params.set(ref, v, undo)
            result = ex.run(st, blk, ln)
        except (Refusal, EvalError, ArithmeticError, ValueError) as e:
            if not isinstance(e, (Refusal, EvalError)):   # a case the interpreter's own checks missed: a bug
                e = Refusal("unsupported", f"pmctl cannot interpret this block ({type(e).__name__}: {e}); this "
                                           "is a fault in pmctl's interpreter: please report it with the program",
                            None)
            self.params.restore(undo)
            del self.moves[mark:]
            del self.messages[nmsg:]
            ex.events = []
            for k, msg, c in ex.notes:
                self.problem(src.path, ex.line, c, k, msg)
            kind = getattr(e, "kind", "syntax")
            self.problem(src.path, ex.line, e.column, kind, e.message)
            if blk is not None:
                ex.keep_modes(blk)                  # the lines after it continue in the modes it meant
            return None
        for k, msg, c in ex.notes:
            self.problem(src.path, ex.line, c, k, msg)
        ex.st = st
        return result

    def comments(self, st, ln, i):
        for text, col in ln.comments:
            body = text.strip()
            head, _, rest = body.partition(",")
            key = head.strip().upper()
            if key in ("MSG", "DEBUG", "PRINT") and "," in body:
                msg = rest.strip() if key == "MSG" else self.substitute(rest.strip())
                self.messages.append((i + 1, msg))
                if key != "PRINT":
                    self.ex.event("message", msg)
            elif key in ("LOGOPEN", "LOGAPPEND", "LOGCLOSE", "LOG", "PROBEOPEN", "PROBECLOSE") and \
                    (key in ("LOGCLOSE", "PROBECLOSE") or "," in body):
                raise Refusal("unsupported", f"({key.lower()},...): writing files from a program is not supported",
                              col)
            elif key == "ABORT" and "," in body:
                raise Refusal("unsupported", "(ABORT,...) is not supported: end the program with M2", col)

    def substitute(self, text):
        def rep(m):
            try:
                v = self.params.named(m.group(1).replace(" ", "").lower()) if m.group(1) is not None \
                    else self.params.param(int(m.group(2))) if 1 <= int(m.group(2)) <= 5602 else None
            except EvalError:
                v = None
            return "######" if v is None else f"{v:.6f}"
        return _SUBST.sub(rep, text)

    # ------------------------------------------------------------------ a whole program
    def run_program(self, src: Source):
        """Run a program from its first line to M2/M30, its closing '%' or its end. The garbage
        collector is paused meanwhile (the moves are long-lived objects, not garbage: scanning them again
        and again would double the time)."""
        was = gc.isenabled()
        gc.disable()
        try:
            self._run_program(src)
        finally:
            if was:
                gc.enable()

    def _run_program(self, src: Source):
        for fe in src.problems:
            self.problem(src.path, fe.line, fe.column, "syntax", fe.message)
        frames = []
        pc_src, i = src, 0
        percent = None                 # line of the opening '%'
        seen = False
        ended = False
        cfg = self.cfg
        while True:
            n = len(pc_src.lines)
            if i >= n:
                if frames:
                    f = frames[-1]
                    self.problem(pc_src.path, n, None, "syntax", f"the file ends inside subroutine o{f.label} "
                                                                 "(its endsub is missing)")
                    frames.pop()
                    self.params.pop_call(f.saved)
                    pc_src, i = f.src, f.ret
                    continue
                break
            try:
                ln = pc_src.lex(i)
            except LexError as e:
                self.problem(pc_src.path, i + 1, e.column, "syntax", e.message)
                seen = True
                i += 1
                continue
            except EvalError as e:
                self.problem(pc_src.path, i + 1, e.column, "syntax", e.message)
                i += 1
                continue
            if ln.grbl is not None:
                # grbl's queries ($ $$ $# $G $I $N ?) ask the console something and change nothing: skipped;
                # its other system commands (homing, settings, jogs...) are the console's, not a job's
                cmd = "".join(ln.grbl.split()).upper()
                if cmd not in GRBL_QUERIES:
                    self.problem(pc_src.path, i + 1, None, "unsupported",
                                 f"{ln.grbl.split()[0]}: grbl's system commands go to the console, not in a job "
                                 "file (only its queries $ $$ $# $G $I $N ? are skipped here)")
                i += 1
                continue
            if ln.blank and not ln.percent and not ln.comments:
                i += 1
                continue
            if ln.delete and cfg.block_delete:
                i += 1
                continue
            if ln.percent:
                if pc_src is src and not frames:
                    if percent is not None:
                        ended = True
                        break
                    if seen:
                        self.problem(src.path, i + 1, 1, "syntax", "'%' inside a program that did not start with '%'")
                    else:
                        percent = i + 1
                        seen = True
                else:
                    self.problem(pc_src.path, i + 1, 1, "syntax", "'%' inside a subroutine")
                i += 1
                continue
            if not ln.blank:
                seen = True
            self.blocks += 1
            if self.blocks > MAX_BLOCKS:
                self.problem(pc_src.path, i + 1, None, "unsupported",
                             f"more than {MAX_BLOCKS} blocks executed: an endless loop? (split the job otherwise)")
                break
            if ln.oword is not None:
                try:
                    nxt = self.oword(pc_src, i, ln, frames)
                except (FlowError, EvalError, Refusal) as e:
                    kind = getattr(e, "kind", "syntax")
                    self.problem(pc_src.path, i + 1, e.column, kind, e.message)
                    nxt = (pc_src, self.past_structure(pc_src, i, ln))
                if nxt is None:
                    ended = True
                    break
                pc_src, i = nxt
                continue
            ex = self.ex
            ex.line, ex.file = i + 1, pc_src.label
            if ex.fast_line(ln):
                i += 1
                continue
            result = self.block(pc_src, i, ln)
            if result is None:
                i += 1
                continue
            if result == "end":
                ended = True
                break
            if result == "m99":
                if not frames or frames[-1].kind != "fanuc":
                    ended = True              # M99 in the main program ends it (as LinuxCNC's rs274)
                    break
                f = frames[-1]
                f.repeat -= 1
                if f.repeat > 0:
                    i = f.counters["start"] + 1
                    continue
                frames.pop()
                self.ex.leave_level(len(self.params.frames) - 1)
                self.params.pop_call(f.saved)
                pc_src, i = f.src, f.ret
                continue
            if isinstance(result, tuple) and result[0] == "m98":
                _, number, count = result
                where = src.fanuc.get(number)
                if where is None:
                    self.problem(pc_src.path, i + 1, None, "syntax", f"M98 P{number}: no subprogram O{number} "
                                                                     "(O<number> ... M99) in this file")
                    i += 1
                    continue
                if count == 0:
                    i += 1
                    continue
                if len(frames) >= MAX_CALL_DEPTH:
                    self.problem(pc_src.path, i + 1, None, "syntax", f"calls nested deeper than {MAX_CALL_DEPTH}")
                    i += 1
                    continue
                f = _Frame(pc_src, i + 1, self.params.push_call([]), str(number), "fanuc", count)
                f.counters["start"] = where[0]
                frames.append(f)
                pc_src, i = src, where[0] + 1
                continue
            i += 1
        if percent is not None and not ended:
            self.problem(src.path, percent, None, "syntax", "the program starts with '%' but has no closing '%' "
                                                            "(nor M2/M30)")
        self.finish()

    def past_structure(self, s: Source, i, ln):
        """Where to go on after an O-word whose expression could not be evaluated: past the structure it
        opens or tests (an if, a loop), so a condition that cannot be known does not run its body."""
        j = s.jump.get(i)
        kw = ln.oword.keyword
        if j is None:
            return i + 1
        if kw in ("if", "elseif"):
            return j[1] + 1
        if kw == "while" and j[0] == "dowhile":
            return i + 1                              # the closing while of a do: leave the loop
        if kw in ("while", "repeat"):
            return j[1] + 1
        return i + 1

    def finish(self):
        ex = self.ex
        st = ex.st
        if st.cq:
            ex.comp.dequeue(st)
        ex.flush_events(st)

    # ------------------------------------------------------------------ O-words
    def oword(self, s: Source, i, ln, frames):
        ow = ln.oword
        kw, label = ow.keyword, ow.label
        p = self.params
        p.column = ow.column
        if kw == "":                                   # a Fanuc program number / subprogram
            j = s.jump.get(i)
            if j is not None and j[0] == "fanuc":
                return s, j[1] + 1                      # a subprogram: skipped by the main flow
            return s, i + 1
        if kw == "sub":
            end = s.jump.get(i)
            return s, (end + 1 if isinstance(end, int) else i + 1)
        if kw in ("endsub", "return"):
            if not frames or frames[-1].kind != "sub":
                if kw == "return" and not frames:
                    raise FlowError(f"o{label} return outside a subroutine", i + 1, ow.column)
                return s, i + 1
            f = frames.pop()
            if ow.expr is not None:
                p.set_return(value(ow.expr, p))
            else:
                p.set_return(None)
            self.ex.leave_level(len(p.frames) - 1)
            p.pop_call(f.saved)
            return f.src, f.ret
        if kw == "call":
            args = [value(a, p) for a in ow.args]
            target = s.subs.get(label)
            tsrc = s
            if target is None and label.startswith("<"):
                found = self.subfiles.find(label[1:-1])
                if found is not None:
                    tsrc = found
                    for fe in found.problems:
                        self.problem(found.path, fe.line, fe.column, "syntax", fe.message)
                    found.problems = []
                    target = found.subs.get(label)
            if target is None:
                where = ""
                if label.startswith("<"):
                    sp = ", ".join(str(d) for d in self.cfg.subroutine_path) or "none configured"
                    where = (f" nor {label[1:-1]}.ngc on the subroutine path ({sp}; [interpreter] subroutine_path in "
                             "the service config)")
                raise FlowError(f"o{label} call: no subroutine o{label} in this file{where}", i + 1, ow.column)
            if len(frames) >= MAX_CALL_DEPTH:
                raise FlowError(f"subroutine calls nested deeper than {MAX_CALL_DEPTH} (endless recursion?)", i + 1,
                                ow.column)
            frames.append(_Frame(s, i + 1, p.push_call(args), label, "sub"))
            p.globals["_value_returned"] = 0.0
            return tsrc, target[0] + 1
        j = s.jump.get(i)
        if j is None:
            return s, i + 1                            # a broken structure (reported by the scan)
        if kw in ("if", "repeat", "do") or (kw == "while" and j[0] == "while"):
            # LinuxCNC: a label names one structure; two that run at different lines are an error
            key = (id(s), s.scope.get(i), label)
            first = self.labels.setdefault(key, i)
            if first != i:
                raise FlowError(f"o{label} {kw}: duplicate O-word label, already used at line {first + 1} (give "
                                "every structure a label of its own)", i + 1, ow.column)
        counters = frames[-1].counters if frames else self.main_counters
        if kw == "if":
            chain, endif = j
            for k in chain[:-1]:
                if k == i:
                    cond = value(ow.expr, p)
                else:
                    bl = s.lex(k).oword
                    if bl.keyword == "else":
                        return s, k + 1
                    p.column = bl.column
                    cond = value(bl.expr, p)
                if cond != 0.0:
                    return s, k + 1
            return s, endif + 1
        if kw in ("elseif", "else"):
            return s, j[1] + 1                          # fell through a taken branch
        if kw == "endif":
            return s, i + 1
        if kw == "while":
            if j[0] == "dowhile":
                if value(ow.expr, p) != 0.0:
                    return s, j[1] + 1
                return s, i + 1
            if value(ow.expr, p) != 0.0:
                return s, i + 1
            return s, j[1] + 1
        if kw == "endwhile":
            return s, j[1]
        if kw == "do":
            return s, i + 1
        if kw == "repeat":
            key = (id(s), i)
            if key not in counters:
                n = value(ow.expr, p)
                counters[key] = int(n) if n > 0 else 0
            if counters[key] <= 0:
                counters.pop(key, None)
                return s, j[1] + 1
            return s, i + 1
        if kw == "endrepeat":
            key = (id(s), j[1])
            counters[key] = counters.get(key, 1) - 1
            if counters[key] > 0:
                return s, j[1] + 1
            counters.pop(key, None)
            return s, i + 1
        if kw in ("break", "continue"):
            loop_kind, start, end = j
            if loop_kind == "repeat":
                if kw == "break":
                    counters.pop((id(s), start), None)
                    return s, end + 1
                return s, end                           # endrepeat counts it
            if loop_kind == "do":
                if kw == "break":
                    return s, end + 1
                return s, end                           # the closing while tests it
            if kw == "break":
                return s, end + 1
            return s, start                             # the while tests again
        return s, i + 1

    # ------------------------------------------------------------------ results
    def job(self, source) -> Job:
        pts = [m.tip for m in self.moves if m.kind != DWELL and m.kind != EVENT]
        lines = [m.line for m in self.moves if m.kind != DWELL and m.kind != EVENT]
        return Job(tuple(self.moves), str(source), np.array(pts, float).reshape(-1, 3), np.array(lines, int),
                   tuple(self.messages))
