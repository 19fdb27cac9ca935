"""Benchmarks behind ``splatstyler bench``: each module times one job against a reference in the same run and
prints a table (or ``--json``). They drive the engine from outside, as the app does; the engine never imports them.
"""
