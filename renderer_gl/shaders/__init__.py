"""GLSL sources of renderer_gl (a package so that setuptools installs its *.glsl files as package data)."""
