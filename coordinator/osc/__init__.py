"""Show control over OSC: the rig driven from QLab, TouchDesigner, Resolume, disguise or a
lighting desk, which speak Open Sound Control over UDP.

Off unless rig.toml has an ``[osc]`` table with ``listen`` (:mod:`coordinator.osc.config`). The
coordinator then listens on that UDP address and hears only the senders its ``allow`` list names
(default: this machine). **OSC has no authentication**: anyone who can send a datagram from an
allowed address drives the show, so keep the list to the show controllers and the port on the
show network. Every command lands in the rig's action log as ``osc:<sender ip>``.

The address space (:mod:`coordinator.osc.commands`):

=============================================  =================================================
``/shadowless/go``                             fire the next cue
``/shadowless/back``                           fire the cue before the current one
``/shadowless/jump CUE_ID``                    fire the cue with this id
``/shadowless/play ASSET [LOOP]``              play an asset from its start (LOOP 1: loop it)
``/shadowless/pause``, ``/shadowless/resume``  hold the playing asset, go on
``/shadowless/stop``                           stop: the rig's content again (black without one)
``/shadowless/blackout``                       stop and show black
``/shadowless/gain SLOT|* VALUE``              one projector's gain, or every one's (0..16)
``/shadowless/status``                         reply with the status messages to the sender
``/shadowless/subscribe [PORT]``               the status on every change, for 10 minutes
``/shadowless/unsubscribe [PORT]``             no more status
``/shadowless/timecode HH:MM:SS:FF|SECONDS``   an external clock the playing show chases
=============================================  =================================================

MIDI timecode (``mtc_port`` in ``[osc]``, or ``shadowless coordinator --mtc-port NAME``; the
optional ``midi`` extra) drives the same chase as ``/shadowless/timecode``
(:mod:`coordinator.osc.mtc`, :mod:`coordinator.osc.mtc_input`).

A refused command is answered ``/shadowless/error ADDRESS REASON``. The status messages
(``/shadowless/cue/current``, ``/cue/next``, ``/show``, ``/showing``, ``/nodes``, ``/lost``) are
described in :mod:`coordinator.osc.feedback`, the timecode and its chase in
:mod:`coordinator.osc.timecode`, the server in :mod:`coordinator.osc.service`.
"""
