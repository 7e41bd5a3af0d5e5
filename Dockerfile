# mavattitude in a container: build a wheel, install it with its pinned run-time dependencies into a slim
# runtime, run as an unprivileged user in the dialout group. Needs BuildKit (`RUN --mount`): the default
# builder since Docker 23; on an older engine (Debian 12's docker.io is 20.10) set DOCKER_BUILDKIT=1.
# tests/deploy/test_docker.py builds this image and runs it as the README's "In Docker" section says.
#
#   DOCKER_BUILDKIT=1 docker build -t mavattitude .
#   docker run -d --name mavattitude --restart=unless-stopped -p 14551:14551/udp \
#       -v /etc/mavattitude:/etc/mavattitude:ro mavattitude
#
# The base image is pinned to an exact patch release; pin its digest too for byte-identical rebuilds
# (`docker buildx imagetools inspect python:3.11.14-slim-bookworm` prints it).
ARG PYTHON_IMAGE=python:3.11.14-slim-bookworm

FROM ${PYTHON_IMAGE} AS build
ENV PIP_DISABLE_PIP_VERSION_CHECK=1 \
    PIP_NO_CACHE_DIR=1
WORKDIR /src
COPY pyproject.toml README.md ./
COPY mavattitude ./mavattitude
# pip fetches setuptools from PyPI for the build (build isolation): it shapes how the pure-Python wheel is
# packed, not what it contains.
RUN pip wheel --no-deps --wheel-dir /wheels .

FROM ${PYTHON_IMAGE}
ENV PIP_DISABLE_PIP_VERSION_CHECK=1 \
    PIP_NO_CACHE_DIR=1 \
    PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    MAVATTITUDE_ALIVE_FILE=/tmp/mavattitude.alive
# The run-time dependencies come from docker/requirements.lock: exact versions with their hashes (every
# one a prebuilt wheel for CPython 3.11 on x86_64 and aarch64, so no compiler), so a rebuild gets the same
# packages. Their layer comes first: a change to the code alone rebuilds only the wheel's layer below.
RUN --mount=type=bind,source=docker/requirements.lock,target=/tmp/requirements.lock \
    pip install --no-cache-dir --require-hashes -r /tmp/requirements.lock \
    && groupadd --system --gid 10001 mavattitude \
    && useradd --system --uid 10001 --gid 10001 --groups dialout --no-create-home --shell /usr/sbin/nologin mavattitude \
    && mkdir -p /etc/mavattitude
# The config comes from the host: mount a directory holding config.yaml (see configs/*.yaml), read-only.
VOLUME ["/etc/mavattitude"]
# The wheel alone, bind-mounted from the build stage (never copied into a layer); pip check: nothing missing.
RUN --mount=type=bind,from=build,source=/wheels,target=/wheels \
    pip install --no-cache-dir --no-deps /wheels/*.whl \
    && pip check
# A uid with no group: Docker then applies the user's groups from /etc/group, dialout (gid 20) among them,
# which opens a serial device passed with `--device /dev/ttyACM0`. (`USER 10001:10001` would drop them.)
USER 10001
WORKDIR /tmp
# The main loop refreshes $MAVATTITUDE_ALIVE_FILE every second; older than 5 s means the loop is stuck.
# (After 10 s stuck the process exits by itself, with its tracebacks in the log, and --restart restarts it.)
HEALTHCHECK --interval=2s --timeout=2s --start-period=10s --retries=2 \
    CMD ["python", "-c", "import os, sys, time; sys.exit(time.time() - os.stat(os.environ['MAVATTITUDE_ALIVE_FILE']).st_mtime > 5)"]
# mavattitude's own MAVLink port (the ground station keeps 14550): the config's `link.connect` is
# udpin:0.0.0.0:14551, as in configs/*.yaml.
EXPOSE 14551/udp
ENTRYPOINT ["mavattitude"]
CMD ["run", "--config", "/etc/mavattitude/config.yaml"]
