"""``python -m rbgp_cli`` runs the command line."""

from rbgp_cli.cli.app import main

if __name__ == "__main__":
    main()
