"""Device drivers, each an adapter behind one small interface (drivers/base.py): the LUCID
camera over GenICam (harvesters), the AT901 tracker over emScon TCP, the robot base over a
serial line. Below the daemon: nothing here imports it.
"""
