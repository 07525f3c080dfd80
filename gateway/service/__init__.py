"""The daemon: main loop, systemd notify, the console's view of it."""
