"""Experiments: one module per paper figure or table, the demo, and the HTML report.

Functions here compute first and plot only when asked; plotting libraries are
imported inside the plotting functions.
"""
