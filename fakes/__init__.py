"""The simulated world and a fake for every device, speaking its protocol; the simulator's
ritad plugin (fakes/plugin.py). Enters the product only through entry points and config.
"""
