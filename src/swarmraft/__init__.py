"""SwarmRaft: trustworthy drone-swarm positions under GNSS jamming and spoofing."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("swarmraft")
except PackageNotFoundError:  # running from a source tree without installation
    __version__ = "0.0.0+source"
