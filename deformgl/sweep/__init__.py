"""Sweeps: one scene over a set or product of scene-key overrides, each variant rendered and/or
measured, run on Dask distributed (a LocalCluster of worker processes, or any cluster by its
scheduler address), gathered into one table (CSV, JSON) and a contact sheet.

:mod:`deformgl.sweep.sweepfile` reads sweep files, :mod:`deformgl.sweep.task` runs one variant in a
worker (one EGL context per worker thread), :mod:`deformgl.sweep.runner` schedules and gathers,
:mod:`deformgl.sweep.sheet` writes the table and the contact sheet, :mod:`deformgl.sweep.command` is
``deformgl sweep``.
"""
