"""Errors a node raises; each message says what the operator can do."""


class NodeError(Exception):
    """Base of every node error."""


class Refused(NodeError):
    """The coordinator refused this node (protocol, token, slot): needs operator action."""


class CoordinatorNotTrusted(NodeError):
    """The peer could not prove it knows the rig token (rogue or misconfigured advertiser)."""


class DiscoveryError(NodeError):
    """No usable coordinator was found over mDNS."""
