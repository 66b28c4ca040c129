"""The vehicle side's configuration sections: the MAVLink connection, telemetry wishes and the downlink.

They live here so that ``vehicle/`` needs nothing from the app; ``companion.config.Config`` embeds them as its
``mavlink``, ``telemetry`` and ``surface`` sections, and the app hands each object the section it needs.
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field


class _Section(BaseModel):
    model_config = ConfigDict(extra="forbid", validate_assignment=True)


class MavlinkConfig(_Section):
    connection: str | None = "udpin:127.0.0.1:14551"
    """pymavlink connection string (udpin:, udpout:, tcp:, tcpin:, /dev/ttyACM0,115200); null: no vehicle link."""
    system_id: int | None = Field(None, ge=1, le=254)
    """The vehicle's system id; None: learnt once from the first autopilot heartbeat and kept (1 until then). Never 255."""
    component_id: int = Field(100, ge=1, le=254)
    """This companion's component id: 100-105 are cameras (QGroundControl finds those), 191-194 onboard computers."""
    heartbeat_timeout_s: float = Field(3.0, gt=0)
    reconnect_initial_s: float = Field(0.5, gt=0)
    reconnect_max_s: float = Field(10.0, gt=0)
    signing_key_file: str | None = None
    """MAVLink 2 signing key: a file with 32 raw bytes or a passphrase (SHA-256, as MAVProxy's `signing setup`).
    With a key everything sent is signed and unsigned parameter writes, commands and FTP writes are ignored;
    null: no signing (docs/security.md)."""
    signing_timestamp_file: str | None = None
    """Where the last signing timestamp is kept so a restart never reuses one; null: beside the key file, one per
    component id (KEY.comp100.timestamp)."""
    accept_unsigned_reads: bool = True
    """With a key, still accept unsigned reads (heartbeats, telemetry, parameter and FTP reads), as ArduPilot does."""
    unsigned_autopilot: bool = False
    """With a key, still take an autopilot that does not sign (its heartbeat and telemetry unsigned): anyone on the
    link can then pose as it and tag frames. False: only the autopilot's signed messages are used (docs/security.md)."""


class TelemetryConfig(_Section):
    attitude_hz: float = Field(10.0, gt=0)
    position_hz: float = Field(5.0, gt=0)
    pressure_hz: float = Field(5.0, gt=0)
    stale_after_s: float = Field(1.0, gt=0)
    """A frame whose nearest telemetry sample is older than this is tagged stale, never given a made-up pose."""
    history_s: float = Field(30.0, gt=0)
    fluid_density: float = Field(1025.0, gt=900, lt=1100)
    """kg/m^3: 1025 sea water, 997 fresh water."""
    surface_pressure_hpa: float = Field(1013.25, gt=800, lt=1200)
    rate_grace_s: float = Field(3.0, ge=0.2, le=60)
    """How long an asked-for message may take to arrive at half its rate before it is asked for again (the wait
    then doubles); after three unanswered asks it is declared missing (no DVL or USBL, or a signing autopilot)."""
    position_wait_s: float = Field(30.0, ge=0, le=600)
    """No position source (LOCAL_POSITION_NED never comes) is said only once the autopilot has been up this long:
    ArduSub's EKF sets its origin, and starts sending positions, ~16 s after boot."""
    rate_listen_s: float = Field(1.0, ge=0, le=10)
    """When the autopilot is found, listen this long first: a message already arriving at 80% of its rate or more
    (a ground station may have set it) is not asked for, so the companion never lowers it."""


class SurfaceConfig(_Section):
    budget_bytes_per_s: int = Field(2000, ge=100)
    """All the companion sends (heartbeat, answers, status, thumbnails, FTP) shares this wire budget."""
    thumbnail_bytes: int = Field(2500, ge=300, le=65000)
    thumbnail_format: Literal["jpeg", "webp"] = "jpeg"
    thumbnail_max_side: int = Field(160, ge=16, le=1024)
    push: bool = True
    """Push each new summary frame with DATA_TRANSMISSION_HANDSHAKE + ENCAPSULATED_DATA."""
    ftp: bool = True
    ftp_writable: bool = False
    """Allow uploads (e.g. /config/queries.txt to change the queries live)."""
    status_hz: float = Field(1.0, gt=0, le=10)
