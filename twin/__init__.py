"""The local twin C': estimates become MuJoCo bodies, and the simulation loop runs at haptic rate."""
