"""Interfaces: how people and programs talk to pmctl (the command line; the operator console and the
control socket as they are built)."""
