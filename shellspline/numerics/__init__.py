"""Numerical building blocks shared by every solver: sparse Cholesky (:mod:`.linalg`),
Krylov solvers (:mod:`.krylov`: PCG, Steihaug–Toint), Armijo backtracking
(:mod:`.linesearch`) and the one result record of iterative solvers (:mod:`.result`)."""
