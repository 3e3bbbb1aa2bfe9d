"""What the robot would run: marker detection, pose, and (later) deflection and branch finding."""
