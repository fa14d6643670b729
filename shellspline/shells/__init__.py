"""Shell space (paper 001): LΘA descriptors, the LΘA time spline, Gauss–Newton
reconstruction, the Discrete Shells energy, geodesics, the nonlinear spline, prolongation."""
