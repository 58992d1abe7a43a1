"""Factory's nut-on-bolt screw task on the shared robot and sensors."""
