"""rbgp_cli.kernels"""
