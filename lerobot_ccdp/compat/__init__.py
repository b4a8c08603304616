"""Every adaptation of LeRobot (and MuJoCo) behaviour, in one place, each installed only where it is
needed."""
