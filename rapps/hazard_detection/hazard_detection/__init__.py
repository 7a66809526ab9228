"""Hazard-detection RApp: task (Dynamic Agent) and QR localization (Cloud Agent)."""
