"""Spline cells: an elastic body whose displacement is a quadratic tensor-product B-spline on the
node grid, the nodes its control points (issue 44; the finite cell method of Parvizian, Düster &
Rank 2007 with the B-spline basis of Schillinger & Ruess 2015)."""
