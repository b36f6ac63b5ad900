"""Reading a systemd unit file for the packaging tests."""

from pathlib import Path


def unit_settings(path: Path) -> dict[str, list[str]]:
    """Every Key=value of the unit, all sections together, values in file order (a key such as
    DeviceAllow= may be given more than once). Comments and section headers are skipped."""
    settings: dict[str, list[str]] = {}
    for line in path.read_text().splitlines():
        if line and not line.startswith(("#", ";", "[")):
            key, _, value = line.partition("=")
            settings.setdefault(key, []).append(value)
    return settings
