"""The plane method with a checkerboard (Zhang and Pless): the board's pose in each image,
its cut in each scan, the point-to-plane solve, and the reduced solve for boards that never
tilt."""
