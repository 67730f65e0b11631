"""What the figures of lensdual.visualization share."""


def _plt():
    import matplotlib.pyplot as plt

    return plt


def _headless_plt():
    """pyplot on a backend that writes files (Agg, unless a file backend is in use)."""
    import matplotlib

    if matplotlib.get_backend().lower() not in ("agg", "pdf", "svg", "cairo"):
        matplotlib.use("agg")
    return _plt()
