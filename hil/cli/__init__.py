"""The `railhil` command: one module per subcommand, each with add_subparser() and run(args)."""
