"""rbgp_cli.cli"""
