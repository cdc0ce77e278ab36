"""Bytes to frames: IMU serial formats, streaming and bulk decoders, transports."""
