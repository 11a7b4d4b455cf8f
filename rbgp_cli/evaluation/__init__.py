"""rbgp_cli.evaluation"""
