"""ritad, the daemon on the robot: config, device runners, command server, publishers."""
