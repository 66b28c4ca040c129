"""The live companion: capture, inference, enhancement and MAVLink loops joined by bounded queues."""
