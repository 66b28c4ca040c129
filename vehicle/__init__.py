"""Everything MAVLink: the link, ArduSub telemetry and pose tagging, the camera component and the surface link."""
