"""PyBullet simulation bridge, nominal controllers, MCAP recording and replay."""
