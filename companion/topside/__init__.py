"""The surface tool: receives the companion's captures, thumbnails and status over MAVLink and keeps a gallery.

It runs topside, speaks only MAVLink (as QGroundControl does), and never imports the companion's internals.
"""
