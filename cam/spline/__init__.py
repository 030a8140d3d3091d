"""B-spline surfaces, shared by `fit`, `plan` and `verify`: the surface record (`surface`), basis functions,
design matrices and the one evaluation (`basis`), exact knot insertion (`knots`), pieces between C0 knot
lines (`pieces`), folds (`folds`), the differential geometry of a surface in a machine frame
(`geometry`), and analytic test surfaces (`analytic`)."""
