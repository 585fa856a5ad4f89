"""The ``strauss-fit`` command line (installed as the package ``strauss_fit_cli``)."""
