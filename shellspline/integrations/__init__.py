"""Bridges to the tools animators work in: :mod:`shellspline.integrations.blender`.

The top layer beside :mod:`shellspline.cli`: it uses the pipeline and the file formats and
nothing below imports it.
"""
