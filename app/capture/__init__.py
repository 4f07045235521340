"""The capture side of live ingest: ``sweepcast live RIG SOURCE...`` connects a rig's cameras to the service.

One reader per camera (:mod:`.readers`, sources parsed by :mod:`.sources`) decodes its stream and stamps each frame
with its capture time (:mod:`.clocks`: the camera's own clock where the stream carries it, else its timestamps
anchored at arrival), keeping only its newest frames (:mod:`.mailbox`); :mod:`.assembly` builds frame sets by
capture time within a tolerance, with a missing camera's last frame marked stale; :mod:`.uplink` sends them over the
rig's live socket with each frame's capture time; :mod:`.status` prints what happens; :mod:`.live` runs it all.
Settings: :mod:`.settings` (``SWEEPCAST_LIVE_*``). Nothing here imports the service (``app.main``): it is a client.
"""
