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

#: A ``runmode`` block whose reference point is RA = 150 deg, Dec = -30 deg.
RUNMODE = """\
runmode
    reference     3 150.000000 -30.000000
    end
"""


def par_file(tmp_path, *blocks, name="model.par", head=RUNMODE):
    """Write ``head``, the ``blocks`` and the cosmology block as the Lenstool file
    ``tmp_path / name``; its path."""
    path = tmp_path / name
    path.write_text(head + "".join(blocks) + COSMOLOGY + "fini\n")
    return path
