"""rbgp_cli.io"""
