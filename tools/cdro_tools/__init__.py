"""CDRO-SLAM tools."""
