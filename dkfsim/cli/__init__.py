"""The ``dkfsim`` command line (:func:`dkfsim.cli.main.main`)."""
