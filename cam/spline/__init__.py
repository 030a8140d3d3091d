"""B-spline surfaces, shared by `fit`, `plan` and `verify`: the surface record and its evaluation
(`surface`), basis functions and design matrices (`basis`), exact knot insertion (`knots`), the
differential geometry of a surface in a machine frame (`geometry`), and analytic test surfaces
(`analytic`)."""
