"""Every message and service class we use hashes like the Baxter SDK's.

A type whose md5sum differs cannot talk to a real Baxter (rospy refuses the connection), so this
checks the classes the package actually imports: ``baxter_core_msgs`` through ``baxter_pnp.msgs``,
the standard ones from Debian's python3-*-msgs packages. The reference list is a copy of
``../shared/reference/baxter_md5sums.txt`` (md5sums of the SDK 1.2.0 definitions), kept here so that
CI needs nothing outside the repository; when the shared file exists it must still agree.
"""
import importlib
import os

import pytest

from baxter_pnp import msgs

SHARED_MD5SUMS = os.path.join(os.path.dirname(os.path.abspath(__file__)), '..', '..', 'shared', 'reference',
                              'baxter_md5sums.txt')
REFERENCE_MD5SUMS = """
baxter_core_msgs/AnalogIOState 39af371963dc9e4447e91f430c720b33
baxter_core_msgs/AnalogIOStates 0a05ba3bbb53a8a3b164e34946d619f7
baxter_core_msgs/AnalogOutputCommand a7b945129a083ca4095d48aa94841d85
baxter_core_msgs/AssemblyState 356d9dd237ce73b2667da9235f541933
baxter_core_msgs/AssemblyStates 63427318d41dbd2077c105027ad82a2b
baxter_core_msgs/CameraControl 01e38dd67dfb36af457f0915248629d1
baxter_core_msgs/CameraSettings d133bef4a3bd9a6e490a5dc91d20f429
baxter_core_msgs/CollisionAvoidanceState 30f5cb8ae019f1ffe8b599e6d2e589c7
baxter_core_msgs/CollisionDetectionState 7bde38c182b4d08fdc0635b116f65d04
baxter_core_msgs/DigitalIOState 29d0be3859dae81a66b28f167ecec98c
baxter_core_msgs/DigitalIOStates d434210c6ec20947fec667d6c13d6062
baxter_core_msgs/DigitalOutputCommand 23f05028c1a699fb83e22401228c3a9e
baxter_core_msgs/EndEffectorCommand c003234e90416f2ca02ac7837c42cbb7
baxter_core_msgs/EndEffectorProperties 21b83773ab9a35216d11e427573c76cc
baxter_core_msgs/EndEffectorState ade777f069d738595bc19e246b8ec7a0
baxter_core_msgs/EndpointState 44bea01d596ff699fa1447bec34167ac
baxter_core_msgs/EndpointStates a0ca50a066809a5f065f39f37aa028fb
baxter_core_msgs/HeadPanCommand 23b8a3f4b7ee9de7099d029e57660a8c
baxter_core_msgs/HeadState 71c43b264307205358e7e49be5601348
baxter_core_msgs/JointCommand 19bfec8434dd568ab3c633d187c36f2e
baxter_core_msgs/NavigatorState 680d121a1f16a32647298b292492fffd
baxter_core_msgs/NavigatorStates 2c2eeb02fbbaa6f1ab6c680887f2db78
baxter_core_msgs/RobustControllerStatus 2f15441b7285d915e7e59d3618e173f2
baxter_core_msgs/SEAJointState d36406dcbb6d860b1b39c4e28f81352b
baxter_core_msgs/URDFConfiguration 0c7028d878027820eed2aa0cbf1f5e4a
baxter_core_msgs/CloseCamera 1067b4a7f008fe1ff4bd9668312773fd
baxter_core_msgs/CloseCameraRequest c1f3d28f1b044c871e6eff2e9fc3c667
baxter_core_msgs/CloseCameraResponse b6e094011a4dfaee5eddf447220446cf
baxter_core_msgs/ListCameras 855b31192ab61744e7deb992d94db7ff
baxter_core_msgs/ListCamerasRequest d41d8cd98f00b204e9800998ecf8427e
baxter_core_msgs/ListCamerasResponse 855b31192ab61744e7deb992d94db7ff
baxter_core_msgs/OpenCamera 73eacff63d5f9cca2d986614515a5c8c
baxter_core_msgs/OpenCameraRequest c4194eee32741c5a98ef8da9666fa6c9
baxter_core_msgs/OpenCameraResponse b6e094011a4dfaee5eddf447220446cf
baxter_core_msgs/SolvePositionIK 18cc92fd96853eb10b34de0b5c7d3cba
baxter_core_msgs/SolvePositionIKRequest 2587e42983d0081d0a2288230991073b
baxter_core_msgs/SolvePositionIKResponse d9b0c2b3932e08421f5094cf62743b9f
std_msgs/Bool 8b94c1b53db61fb6aed406028ad6332a
std_msgs/Empty d41d8cd98f00b204e9800998ecf8427e
std_msgs/Float64 fdb28210bfa9d7c91146260178d9a584
std_msgs/UInt16 1df79edf208b629fe6b81923a544552d
std_msgs/UInt32 304a39449588c7f8ce2df6e8001c5fce
std_msgs/Header 2176decaecbce78abc3b96ef049fabed
sensor_msgs/JointState 3066dcd76a6cfaef579bd0f34173e9fd
sensor_msgs/Image 060021388200f6f0f447d0fcd9c64743
sensor_msgs/CameraInfo c9a58c1b0b154e0e6da7578cb991d214
sensor_msgs/Range c005c34273dc426c67a020a87bc24148
geometry_msgs/PoseStamped d3812c3cbc69362b77dc0b19b345f8f5
geometry_msgs/Pose e45d45a5a1ce597b249e23fb30fc871f
std_srvs/Empty d41d8cd98f00b204e9800998ecf8427e
"""
REFERENCE = [tuple(line.split()) for line in REFERENCE_MD5SUMS.strip().splitlines()]


def _python_class(type_name):
    """Message/service class for 'package/Type': baxter_core_msgs from baxter_pnp.msgs, others from Debian."""
    package, name = type_name.split('/')
    if package == 'baxter_core_msgs':
        modules = (msgs.msg, msgs.srv)
    else:
        modules = []
        for kind in ('msg', 'srv'):
            try:
                modules.append(importlib.import_module(f'{package}.{kind}'))
            except ImportError:
                pass
    for module in modules:
        if hasattr(module, name):
            return getattr(module, name)
    raise AssertionError(f'no Python class for {type_name}')


def test_reference_copy_matches_the_shared_list():
    if not os.path.exists(SHARED_MD5SUMS):
        pytest.skip(f'{SHARED_MD5SUMS} not available on this machine')
    with open(SHARED_MD5SUMS) as f:
        shared = [tuple(line.split()) for line in f if line.strip()]
    assert shared == REFERENCE


@pytest.mark.parametrize('type_name, md5sum', REFERENCE, ids=[name for name, _ in REFERENCE])
def test_md5sum_matches_the_sdk(type_name, md5sum):
    cls = _python_class(type_name)
    assert cls._type == type_name
    assert cls._md5sum == md5sum
