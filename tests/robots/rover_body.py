"""The body of the third robot type tests/test_robot_types.py adds ("rover"): what a new type's
robots/<type>.py holds, here made of the Elektron's parts (URDF, camera, laser, postures, wheel slip)
on a narrower base. Imported only once the test's row is in ontology/robot_types.py."""
from dataclasses import replace

from ontology.robot_types import robot_type
from robots import elektron

SPEC = replace(elektron.SPEC, kind="rover", radius=robot_type("rover").body_radius_m)
