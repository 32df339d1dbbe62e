"""Error types shared across pmctl. Each names where the problem is (file, line, field)."""


class PmctlError(Exception):
    """Base of all errors pmctl reports to a user as one clear line."""


class ConfigError(PmctlError):
    def __init__(self, path, key, reason):
        self.path, self.key, self.reason = str(path), key, reason
        where = self.path if key in (None, "", "-") else f"{self.path}: {key}"
        super().__init__(f"{where}: {reason}")


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
