"""Problem models (dynamics, reward, goal area) as compiled kernels, and the simulator nodes."""
