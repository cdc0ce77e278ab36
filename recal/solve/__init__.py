"""From positions to coefficients: the invariant problem, observability, Levenberg-Marquardt, the fish swarms (NAFSA, SAFSA, OAFSA) in a Monte Carlo loop, consider covariance, convergence."""
