"""The Cloud Agent part of lamp-patrol: the SDK's landmark localization (finds the home's QR codes in
the frames and solves the pose), which `await self.localize()` in the task calls."""
from rapps.sdk.landmark_cloud import LandmarkCloud


class LampPatrolCloud(LandmarkCloud):
    pass
