"""rbgp_cli.viz"""
