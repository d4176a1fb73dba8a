"""A survey of the table with the hand camera, for every task: the arm visits straight-down viewpoints that
together see the reachable table (``baxter_pnp.survey``: planned once per camera model, toured from where the
arm is), the eye looks at each, and the believable blocks go into a ``table_map.TableMap`` (fused across looks).
The map is published for rviz (``/baxter_pnp/table_map``, MarkerArray in ``base``) and as latched JSON
(``/baxter_pnp/table_map_json``). ROS edge.
"""
import hashlib
import json
import os

import numpy as np
import rospy
from std_msgs.msg import String
from visualization_msgs.msg import Marker, MarkerArray

from baxter_pnp import survey, table_map
from baxter_pnp.transforms import matrix_to_pose_msg

TABLE_MAP_TOPIC = '/baxter_pnp/table_map'
TABLE_MAP_JSON_TOPIC = '/baxter_pnp/table_map_json'
MARKER_COLOURS = {'green': (0.1, 0.8, 0.1), 'red': (0.9, 0.1, 0.1), 'blue': (0.1, 0.2, 0.9),
                  'yellow': (0.9, 0.8, 0.1)}


class Survey:
    """Surveys by a connected ``task.session.RobotSession`` with its ``Motion`` and ``Eye``; ``area`` the table
    rectangle (x_min, y_min, x_max, y_max; m in base) to see."""

    def __init__(self, session, motion, eye, area):
        self.session, self.motion, self.eye = session, motion, eye
        self.area = survey.TableRect(*area)
        self._plans = {}            # camera model key -> [T_base_gripper]
        self.view_poses = {}        # view id ('survey_k') -> T_base_gripper (4x4) of the last run's looks
        self._map_pub = rospy.Publisher(TABLE_MAP_TOPIC, MarkerArray, queue_size=1, latch=True)
        self._json_pub = rospy.Publisher(TABLE_MAP_JSON_TOPIC, String, queue_size=1, latch=True)

    def viewpoints(self, camera):
        """The survey's gripper poses for ``camera``: planned on first use (10-15 s of IK on two cores), kept in
        ``$ROS_HOME/baxter_pnp/`` (default ``~/.ros``) under a hash of everything the plan depends on (the table,
        the camera, its mount, the planner's source), so later runs on the same set-up reuse it."""
        session = self.session
        table_z = session.table.z_at(((self.area.x_min + self.area.x_max) / 2, (self.area.y_min + self.area.y_max) / 2))
        T_gripper_camera = session.hand_eye.T_gripper_camera
        with open(survey.__file__, 'rb') as source:
            digest = hashlib.sha1(source.read())
        for part in (np.asarray(self.area, float), np.float64(table_z), camera.K, camera.D, T_gripper_camera,
                     np.array([camera.width, camera.height], float)):
            digest.update(np.ascontiguousarray(part, dtype=float).tobytes())
        key = digest.hexdigest()[:16]
        if key in self._plans:
            return self._plans[key]
        path = os.path.join(os.environ.get('ROS_HOME', os.path.expanduser('~/.ros')), 'baxter_pnp',
                            'survey_%s.npy' % key)
        try:
            self._plans[key] = list(np.load(path))
            rospy.loginfo('%s: survey of the table: %d viewpoints from %s' % (session.log_name,
                                                                             len(self._plans[key]), path))
            return self._plans[key]
        except (OSError, ValueError):
            pass
        plan = survey.plan_survey(self.area, table_z, camera, T_gripper_camera, self.eye.hand_clearance(camera),
                                  session.kinematics)
        rospy.loginfo('%s: survey of the table planned: %d viewpoints' % (session.log_name, len(plan)))
        try:
            os.makedirs(os.path.dirname(path), exist_ok=True)
            partial = '%s.%d.npy' % (path[:-len('.npy')], os.getpid())     # np.save keeps a .npy name
            np.save(partial, np.array(plan))
            os.replace(partial, path)
        except OSError as error:
            rospy.logwarn('%s: survey plan not kept (%s)' % (session.log_name, error))
        self._plans[key] = plan
        return plan

    def run(self, believable, camera):
        """Visit the viewpoints (nearest first) and look at each; the blocks ``believable(observation,
        T_base_camera)`` accepts go into a new TableMap, which is published and returned (its view ids are the keys
        of ``view_poses``: where the gripper was for each look)."""
        session = self.session
        plan = survey.order_viewpoints(self.viewpoints(camera), start=session.limb.endpoint_pose()[:3, 3])
        found = table_map.TableMap()
        self.view_poses = {}
        for k, T_base_gripper in enumerate(plan, start=1):
            session.check_deadline()
            self.motion.move_to_pose(T_base_gripper, 'survey view %d of %d' % (k, len(plan)))
            look = self.eye.look(after_stamp=rospy.get_time())
            kept = [o for o in look.observations if believable(o, look.T_base_camera)]
            found.add_look(table_map.sightings_from_look(kept, look.T_base_camera, look.frame.camera),
                           look.frame.stamp, 'survey_%d' % k)
            self.view_poses['survey_%d' % k] = look.T_base_gripper
        for block in found.blocks():
            rospy.loginfo('%s: table map: %s %s at %s mm (+- %.1f mm, %d view(s))'
                          % (session.log_name, block.colour, block.shape, np.round(1000 * block.position, 1).tolist(),
                             1000 * block.std, block.views))
        self.publish(found)
        return found

    def publish(self, found):
        """The map as rviz markers (a box per block, its colour, in base) and as latched JSON."""
        markers = MarkerArray(markers=[Marker(action=Marker.DELETEALL)])
        for block in found.blocks():
            marker = Marker(type=Marker.CUBE, action=Marker.ADD, ns='table_map', id=int(block.id))
            marker.header.frame_id, marker.header.stamp = 'base', rospy.Time.from_sec(block.last_seen)
            matrix_to_pose_msg(block.T_base_block, marker.pose)
            query = self.eye.query
            marker.pose.position.z -= query.height / 2      # the block frame is its top face
            marker.scale.x = marker.scale.y = query.side_length
            marker.scale.z = query.height
            marker.color.r, marker.color.g, marker.color.b = MARKER_COLOURS.get(block.colour, (0.5, 0.5, 0.5))
            marker.color.a = 0.8
            markers.markers.append(marker)
        self._map_pub.publish(markers)
        self._json_pub.publish(String(json.dumps(json.loads(found.to_json()))))
