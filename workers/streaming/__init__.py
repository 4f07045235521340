"""Virtual-view streaming: the sweep renderer (workers.sweep) on the wire.

Modules (import from them; arrays follow workers.camera conventions, images uint8 BGR):

- ``params``: pydantic models: ``Viewpoint`` (a viewer message), ``Orbit``, ``LookAt``, ``Pose``,
  ``RecordingRequest``, and the job parameters ``RecordingImportParams``, ``BatchRenderParams``,
  ``DemoParams``.
- ``viewpoint``: ``orbit_frame(rig) -> OrbitFrame``, ``rig_up``, ``orbit_camera``,
  ``virtual_camera(view, frame, size)``, ``path_cameras(keys, ats, frame, size, count)``.
- ``framing``: binary messages (4-byte header length, JSON header, payload): ``pack_message``,
  ``unpack_message``, ``unpack_frame_set(data, camera_names) -> FrameSet``, ``FramingError``.
- ``images``: ``image_size`` (from the header), ``decode_image(data, size)``, ``decode_reduced(data, size, factor)`` (JPEG DCT scaling), ``decode_stored``, ``encode_jpeg`` (PNG: ``workers.common.images.encode_png``).
- ``video``: PyAV ``probe_video``, ``decode_frames``, ``H264Writer``.
- ``recording``: checks against the rig (``match_cameras``, ``check_videos``, ``scan_image_zip``,
  ``check_image_sizes``), the archive (``ArchiveWriter``, ``RecordingArchive``), imports
  (``import_videos``, ``import_image_zip``), ``temporal_median``.
- ``background``: ``BackgroundModel``, the per-camera empty-scene model of a live stream.
- ``session``: ``RecordingSession`` / ``LiveSession`` (render a ``Viewpoint`` to a header and a JPEG),
  ``SessionLimits``, ``ViewError``; a recording is rendered from frames shrunk to about the viewer's size
  (``source_factor``, ``shrunk_rig``, ``shrunk_images``).
- ``actor``: the Ray ``SessionActor`` (one per rig and source; idle end; restarts reload from the
  blob store), ``SessionConfig``, ``SessionClient`` (async, API side), ``list_sessions``,
  ``session_info``, ``end_sessions``.
- ``store``: rigs, recordings and live frames in the blob store.
- ``batch``: camera paths and ``render_path`` (H.264 MP4 + zip of depth PNGs).
- ``demo``: ``demo_rig`` (10 cameras, 640x480), ``demo_scene`` (the photographic studio of
  ``workers.synth.studio_scene``), ``build_demo_recording``.
- ``browser``: what a viewer that renders in its browser gets: ``render_spec(rig)`` (the rig at every source
  factor, silhouettes, overlay colours, the renderer's rules), ``frame_atlas`` (a frame set as one image).
- ``rules``: the server's rules as data for the viewer page: ``viewpoint_controls`` (what a viewer may ask for),
  ``renderer_rules`` (RenderOptions' defaults and choices, shader codes and constants, the fill's visibility rule).
- ``job``: job entry points ``run_recording_import``, ``run_batch_render``, ``run_demo_recording``.
"""
