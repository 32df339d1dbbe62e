"""Error types shared across pmctl. Each names where the problem is (file, line, field)."""


class PmctlError(Exception):
    """Base of all errors pmctl reports to a user as one clear line."""


class ConfigError(PmctlError):
    def __init__(self, path, key, reason):
        self.path, self.key, self.reason = str(path), key, reason
        where = self.path if key in (None, "", "-") else f"{self.path}: {key}"
        super().__init__(f"{where}: {reason}")


class MotionRefused(PmctlError):
    """Motion is not allowed now (alarm, rt process down); ``code`` is the grbl error code."""

    def __init__(self, msg, code=9):
        super().__init__(msg)
        self.code = code


class UnreachablePose(PmctlError):
    """A pose outside the workspace or joint limits; the message says which limit."""


class KinematicsError(PmctlError):
    """Forward kinematics failed to converge or left the assembly branch."""


class InputError(PmctlError):
    """Malformed user input (CL data, G-code, recording, console line) with its location."""

    def __init__(self, path, line, reason, column=None):
        self.path, self.line, self.column, self.reason = str(path), line, column, reason
        where = f"{self.path}:{line}" if line is not None else self.path
        if column is not None:
            where += f": column {column}"
        super().__init__(f"{where}: {reason}")


PROBLEM_KINDS = ("syntax", "unsupported", "machine", "planning")


class Problem:
    """One problem of a job, as ``pmctl check`` lists it: where (file, line, column; None when not
    known) and what (``kind``: syntax | unsupported | machine | planning; ``message`` says what to do)."""

    __slots__ = ("file", "line", "column", "kind", "message")

    def __init__(self, file, line, column, kind, message):
        if kind not in PROBLEM_KINDS:
            raise ValueError(f"problem kind {kind!r} is not one of {PROBLEM_KINDS}")
        self.file, self.line, self.column, self.kind, self.message = str(file), line, column, kind, message

    def as_dict(self) -> dict:
        return {"file": self.file, "line": self.line, "column": self.column, "kind": self.kind,
                "message": self.message}

    def __str__(self):
        where = f"{self.file}:{self.line}" if self.line is not None else self.file
        if self.column is not None:
            where += f": column {self.column}"
        return f"{where}: {self.kind}: {self.message}"

    def __repr__(self):
        return f"Problem({self.as_dict()!r})"


class JobProblems(InputError):
    """A job with one or more problems; ``problems`` lists every one found (the message is the first,
    with a count of the others), so a caller that knows only InputError still reports it clearly."""

    def __init__(self, problems):
        self.problems = list(problems)
        if not self.problems:
            raise ValueError("JobProblems needs at least one problem")
        p = self.problems[0]
        more = len(self.problems) - 1
        super().__init__(p.file, p.line, p.message + (f" (and {more} more problem{'s' * (more > 1)}: "
                                                      "pmctl check lists them)" if more else ""),
                         column=p.column)
