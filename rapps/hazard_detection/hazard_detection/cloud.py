"""Cloud Agent part of hazard detection: the SDK's QR-landmark localization (rapps/sdk/landmark_cloud.py,
paper 001 fig. 6) and the stands for the door checks (view.py)."""
import asyncio

from rapps.sdk.landmark_cloud import LandmarkCloud

from .models import ONTOLOGY, DoorViewList, DoorViews, DoorViewSpec
from .view import CameraModel, distinct, door_views


class HazardCloud(LandmarkCloud):
    """The SDK's landmark localization (LandmarkCloud: observe, solve_pose) and where to stand for
    a door check (door_views)."""

    ontology = ONTOLOGY

    async def door_views(self, req: DoorViews) -> DoorViewList:
        return await asyncio.to_thread(views_for, req)


def views_for(req: DoorViews) -> DoorViewList:
    """The stands from which the image method is predicted right for every opening (view.py)."""
    k, c = req.camera.intrinsics, req.camera
    camera = CameraModel(k.fx, k.fy, k.cx, k.cy, c.width, c.height, c.z, c.ahead)
    views = door_views(req.door, req.robot_side, camera, req.rooms, req.doors, robot_radius=req.robot_radius_m,
                       room_rect=req.room.rect if req.room is not None else None,
                       open_threshold_deg=req.open_threshold_deg)
    return DoorViewList(views=[DoorViewSpec(x=v.x, y=v.y, theta=v.theta, look=list(v.look), margin=round(v.margin, 2),
                                            distance_m=v.distance_m, bearing_deg=v.bearing_deg)
                               for v in distinct(views)[:req.limit]])
