# Redis from Debian's packages (bookworm: 7.0), standing in for the official redis image that docker/compose.yaml
# names, which cannot be pulled here. Same interface: redis-server and redis-cli on PATH, data in /data, port 6379.
ARG BASE
FROM ${BASE}
RUN apt-get update \
 && DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends redis-server \
 && rm -rf /var/lib/apt/lists/* && mkdir -p /data
WORKDIR /data
VOLUME /data
EXPOSE 6379
ENTRYPOINT []
CMD ["redis-server", "--protected-mode", "no", "--bind", "0.0.0.0"]
