"""Numerical building blocks shared by every solver: sparse Cholesky, banded solves."""
