"""The planner (``deformgl plan``, ``render --tolerance``): the coarsest grid, the integrator and
the dt whose predicted error of a scene's deflection meets a tolerance, from the measured
accuracy and cost tables (:mod:`deformgl.plan.planner`). A product feature: the CLI's render
path and the shader pack import it, and nothing from :mod:`deformgl.bench`, which measures the
tables it holds."""
