"""The fleet part: several masters share chosen topics and services over Zenoh (docs/fleet.md)."""
