"""``python -m rbgp_cli`` runs the command line."""


def main() -> None:
    """Entry point: signal handling first (a Ctrl-C during the imports is one line, not a traceback)."""
    from rbgp_cli.cli import exit_on_signals, return_freed_memory

    exit_on_signals()
    return_freed_memory()
    from rbgp_cli.cli.app import main as app_main

    app_main()


if __name__ == "__main__":
    main()
