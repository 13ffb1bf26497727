"""Test support shipped with the package: image comparison for golden-image regression tests.
"""
