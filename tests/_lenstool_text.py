"""Text blocks of the small Lenstool parameter files the tests write."""

#: A flat LambdaCDM cosmology block (H0 = 70, Omega_M = 0.3), as Lenstool writes it.
COSMOLOGY = """\
cosmology
    model       1
    H0          70.0
    omegaM      0.3
    omegaX      0.7
    end
"""
