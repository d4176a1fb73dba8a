"""The fake's table clutter in PyBullet: printed chessboards (``scene.Chessboard``), tape and cups
(``scene.Prop``). Pure builders on a PyBullet client; metres and radians in ``base``, ``top_z`` the table top.
"""
import numpy as np
import pybullet as p

from baxter_pnp.sim.scene import TAPE_THICKNESS
from baxter_pnp.transforms import to_xyz_quat

BOARD_COLOR = {'paper': (0.95, 0.95, 0.95), 'ink': (0.05, 0.05, 0.05)}   # chessboard, matte (no specular)
BOARD_INK_LIFT = 2e-5           # m: the black squares above the white board's top (one depth, no z-fighting)
CUP_WALL = 0.004                # m: a cup's wall, seen as a rim around its darker inside
CUP_INSIDE_SHADE = 0.35         # the inside's colour relative to the cup's (shadowed, seen at an angle)
CUP_INSIDE_THICKNESS = 0.001    # m: the disc drawn as the inside (the cup's body is solid)
CUP_INSIDE_LIFT = 1e-4          # m: that disc's top above the cup's (one depth, no z-fighting)


def make_board(client, board, top_z):
    """A ``scene.Chessboard``, visual only: a white box of the whole board and one mesh body of its black
    squares, ``BOARD_INK_LIFT`` above the box in the board frame (``board.T_base_board``). Returns (the
    black squares' body, its mesh (vertices, normals, indices) for the renderer)."""
    T_base_board = board.T_base_board(top_z)
    _, quaternion = to_xyz_quat(T_base_board)
    centre = T_base_board @ [*((np.array(board.pattern) - 1) * board.square / 2), board.thickness / 2, 1.0]
    paper = p.createVisualShape(p.GEOM_BOX, halfExtents=[*np.divide(board.size, 2), board.thickness / 2],
                                rgbaColor=[*BOARD_COLOR['paper'], 1.0], specularColor=[0.0, 0.0, 0.0],
                                physicsClientId=client)
    p.createMultiBody(0.0, -1, paper, centre[:3].tolist(), list(quaternion), physicsClientId=client)
    squares = board.black_squares()                                   # (K, 4, 2), board frame
    vertices = np.concatenate([squares, np.full(squares.shape[:2] + (1,), -BOARD_INK_LIFT)], axis=2)
    vertices = vertices.reshape(-1, 3)
    normals = np.tile([0.0, 0.0, -1.0], (len(vertices), 1))          # board -z: up, out of the table
    # two triangles a square, counter-clockwise seen from above the board (from where the normal points)
    indices = (4 * np.arange(len(squares))[:, None] + [0, 2, 1, 0, 3, 2]).ravel()
    ink = p.createVisualShape(p.GEOM_MESH, vertices=vertices.tolist(), normals=normals.tolist(),
                              indices=indices.tolist(), rgbaColor=[*BOARD_COLOR['ink'], 1.0],
                              specularColor=[0.0, 0.0, 0.0], physicsClientId=client)
    body = p.createMultiBody(0.0, -1, ink, T_base_board[:3, 3].tolist(), list(quaternion), physicsClientId=client)
    return body, (vertices, normals, indices)


def make_prop(client, prop, top_z):
    """The bodies of a ``scene.Prop``: a tape strip (a thin visual box, no collision) or a cup (a fixed solid
    cylinder the arm and blocks collide with, and a darker disc just inside its rim: its inside seen from above).
    Returns the body ids."""
    orientation = p.getQuaternionFromEuler([0.0, 0.0, prop.yaw])
    if prop.shape == 'tape':
        visual = p.createVisualShape(p.GEOM_BOX, halfExtents=[prop.length / 2, prop.width / 2, TAPE_THICKNESS / 2],
                                     rgbaColor=[*prop.color, 1.0], specularColor=[0.1, 0.1, 0.1],
                                     physicsClientId=client)
        return [p.createMultiBody(0.0, -1, visual, [*prop.xy, top_z + TAPE_THICKNESS / 2], orientation,
                                  physicsClientId=client)]
    collision = p.createCollisionShape(p.GEOM_CYLINDER, radius=prop.radius, height=prop.height,
                                       physicsClientId=client)
    visual = p.createVisualShape(p.GEOM_CYLINDER, radius=prop.radius, length=prop.height,
                                 rgbaColor=[*prop.color, 1.0], specularColor=[0.3, 0.3, 0.3], physicsClientId=client)
    cup = p.createMultiBody(0.0, collision, visual, [*prop.xy, top_z + prop.height / 2], orientation,
                            physicsClientId=client)
    inside = p.createVisualShape(p.GEOM_CYLINDER, radius=prop.radius - CUP_WALL, length=CUP_INSIDE_THICKNESS,
                                 rgbaColor=[*(CUP_INSIDE_SHADE * c for c in prop.color), 1.0],
                                 specularColor=[0.0, 0.0, 0.0], physicsClientId=client)
    centre = top_z + prop.height + CUP_INSIDE_LIFT - CUP_INSIDE_THICKNESS / 2     # its top just above the rim's
    return [cup, p.createMultiBody(0.0, -1, inside, [*prop.xy, centre], orientation, physicsClientId=client)]
