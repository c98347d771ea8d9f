"""The paper's box-target method (Algorithm 1): picks of the box's ends, P3P, Horn's
method, RANSAC, Levenberg-Marquardt, the pick assist and the session's solve."""
