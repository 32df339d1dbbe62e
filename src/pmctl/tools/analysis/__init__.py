"""Analyses of the mechanism and the controller (pmctl analyze ...)."""
