"""The ``recal`` command line: one small module per subcommand (see ``main.SUBCOMMANDS``)."""
