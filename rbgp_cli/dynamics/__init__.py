"""rbgp_cli.dynamics"""
