# The S3 stand-in for the verification run: MinIO's image (docker/compose.yaml) cannot be pulled here, and
# neither Debian nor PyPI ship MinIO. moto's server is installable from PyPI, is what the test suite already
# runs the S3 blob store against (multipart upload, ranged get, copy, list_objects_v2, delete_objects), and
# starts in a second. It keeps objects in memory: its container is not part of the compose project, so
# `down`/`up` of the stack leaves it running (MinIO's own volume is not what this verifies).
ARG BASE
FROM ${BASE}
RUN python3 -m venv /opt/moto \
 && /opt/moto/bin/pip install --no-cache-dir 'moto[s3]==5.1.*' 'flask>=3,<4' 'flask-cors>=5,<7'
EXPOSE 9000
ENTRYPOINT ["/opt/moto/bin/moto_server", "-H", "0.0.0.0", "-p", "9000"]
