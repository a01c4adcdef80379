"""Clamp design: search the double-toggle family for a designer's targets (issue 29).

Layer: imports :mod:`toggle` and :mod:`controllers`, never :mod:`hil`; neither of those
imports it. ``toggle design`` is its command line (:mod:`toggle_cli.design`).
"""
