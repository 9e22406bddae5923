"""MuJoCo world building, actors, camera rigs, rendering, sensor models,
ground-truth extraction, and the on-disk sequence format.

Importing this package, or its sequence reader/writer, never imports MuJoCo or
OpenGL: consumers of sequences (detectors, eval, external tools) must not pay
for, or depend on, a GL context.
"""
