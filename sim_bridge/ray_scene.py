"""What the lidars see of a ``SimWorld``: ``RayScene``, its bodies in a client of their own.

Lidars (``sim_bridge.lidar``) cast their rays into ``ray_scene()``, a second
PyBullet client made on first use: every present obstacle copied at once with
Bullet's default collision margin (rays miss most margin-0 shapes, and a
lazily made body cannot be seen before it exists), each robot as the upright
cylinder of its footprint ``radius`` over its body's z range, moved to the
current time on each call.  The world's own bodies, physics, closest points
and collision checks never see it.
"""
import pybullet as pb

from sim_bridge.obstacle_bodies import ObstacleBody


class RayScene:
    """What lidars see of a world: ray-only copies of its bodies in a PyBullet client of their own.

    Every obstacle is copied as soon as it is present (not on first use: a ray cannot ask
    for the bodies it would hit) with Bullet's default collision margin (rays miss most
    shapes of margin 0), and every robot is an upright cylinder of its footprint
    ``radius`` over its body's z range (a robot's CYLINDER marker, as the filter models
    it).  ``sync(time)`` moves them to the world's state.  Nothing here takes part in the
    world's physics, contacts or closest points: it is another client.
    """

    def __init__(self, obstacles, plants):
        """Connect a DIRECT client; copy the present obstacles, make a proxy per robot."""
        self.client = pb.connect(pb.DIRECT)
        self._sources = obstacles
        self._copies = [ObstacleBody(o.spec, o.footprint.index, self.client, lazy=False,
                                      exact=False) for o in obstacles]
        self._plants = plants
        self.proxies = {}
        for plant in plants:
            _, _, z_min, z_max = plant.extent()
            shape = pb.createCollisionShape(pb.GEOM_CYLINDER, radius=plant.spec.radius,
                                            height=z_max - z_min, physicsClientId=self.client)
            self.proxies[plant.spec.name] = pb.createMultiBody(0.0, shape,
                                                               physicsClientId=self.client)
        self.sync(0.0)

    def sync(self, time):
        """Copy pop-ups that have appeared, move moving obstacles and robot proxies to ``time``."""
        for source, copy in zip(self._sources, self._copies):
            if source.present and not copy.present:
                copy.appear(time)
            elif copy.moving and copy.present:
                copy.place(time)
        for plant in self._plants:
            position, _, z_min, z_max = plant.extent()
            pb.resetBasePositionAndOrientation(
                self.proxies[plant.spec.name], (position[0], position[1], 0.5 * (z_min + z_max)),
                (0.0, 0.0, 0.0, 1.0), physicsClientId=self.client)

    def close(self):
        """Disconnect the client."""
        pb.disconnect(physicsClientId=self.client)
