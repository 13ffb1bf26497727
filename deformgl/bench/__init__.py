"""Every ``deformgl bench`` study: timing and report helpers, charts, and the studies themselves
(speed ratios against a baseline run in the same process).
"""
