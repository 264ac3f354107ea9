"""The ``flight-fdi`` command line tool (see ``flight_fdi.cli.main``)."""
