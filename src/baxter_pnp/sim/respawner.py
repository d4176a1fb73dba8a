"""Acts out ``scene.respawn`` (soak tests) for ``sim.world.SimWorld``: a block that was lifted and has been put down and
let go is moved to the next of its respawn poses."""
import numpy as np
import pybullet as p

RESPAWN_LIFT = 0.03             # m: a block counts as lifted once its underside is this far above the table top
RESPAWN_TIP_CLEARANCE = 0.08    # m: every gripper tip must be this far above the block's top before a respawn
RESPAWN_STILL_SPEED = 0.01      # m/s: a block whose points all move slower than this is at rest (resting
                                # blocks jitter at up to ~3 mm/s in PyBullet, a sliding or rocking one is faster)


class Respawner:
    """Acts out a ``scene.Respawn``: watches its block after every step and re-places it when it is due.

    The block is *lifted* once its underside (axis-aligned bounding box) rises ``RESPAWN_LIFT`` above the
    table top. After that, it is due for a respawn when, for ``respawn.delay`` seconds of simulated time
    without a break, it touches the table at rest (no point of it faster than ``RESPAWN_STILL_SPEED``,
    bounded by |v| + |w| R, R its top face's circumradius) and every gripper tip (``<side>_gripper``
    origin) is ``RESPAWN_TIP_CLEARANCE`` above the block's top: the finger pads end 5 mm below that
    origin, so neither finger can touch the block then, whether the gripper is open or closed (it has
    been let go). Then it is put at rest on the table at the next pose (cycling) and ``count`` grows.
    """

    def __init__(self, world, respawn):
        self._world = world
        self.respawn = respawn
        self.body = world._blocks[respawn.object]
        self.radius = world.scene.objects[respawn.object].model.circumradius     # m
        self.count = 0
        self.lifted = False
        self._settled_since = None        # simulated time (s) since which the block has been down and let go

    def update(self):
        world, client = self._world, self._world._client
        (_, _, bottom), (_, _, top) = p.getAABB(self.body, physicsClientId=client)
        table_z = world.scene.table.top_z
        if not self.lifted:
            self.lifted = bottom >= table_z + RESPAWN_LIFT
            return
        if not self._settled(top):
            self._settled_since = None
        elif self._settled_since is None:
            self._settled_since = world.time
        elif world.time - self._settled_since >= self.respawn.delay - 1e-9:
            x, y, yaw = self.respawn.poses[self.count % len(self.respawn.poses)]
            world.place_object(self.respawn.object, (x, y), yaw)
            self.count += 1
            self.lifted, self._settled_since = False, None

    def _settled(self, top):
        """True if the block rests on the table with every gripper tip clear above its ``top`` (z, m)."""
        world, client = self._world, self._world._client
        linear, angular = p.getBaseVelocity(self.body, physicsClientId=client)
        if np.linalg.norm(linear) + np.linalg.norm(angular) * self.radius >= RESPAWN_STILL_SPEED:
            return False
        if not p.getContactPoints(self.body, world._table, physicsClientId=client):
            return False
        return all(world.link_pose(f'{side}_gripper')[2, 3] >= top + RESPAWN_TIP_CLEARANCE for side in world._grippers)
