"""The marker target: a V of two ChArUco faces whose pose the camera reads by itself, its
V found in each scan, and the plane method's solve on both faces."""
