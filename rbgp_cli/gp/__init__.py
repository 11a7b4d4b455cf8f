"""rbgp_cli.gp"""
