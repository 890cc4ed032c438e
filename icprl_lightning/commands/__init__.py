"""Every subcommand's argument parsing and ``main(argv)``; the library modules import no argparse."""
