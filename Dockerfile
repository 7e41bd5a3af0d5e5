# syntax=docker/dockerfile:1
# mavattitude in a container: build a wheel, install it alone into a slim runtime, run as a non-root user.
# No Docker engine runs on the development machines: tests/test_packaging.py lints this file (hadolint)
# and replays its build and run steps in a plain venv.
#
#   docker build -t mavattitude .
#   docker run --rm -p 14550:14550/udp -v /etc/mavattitude:/etc/mavattitude:ro mavattitude
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
RUN pip wheel --no-deps --wheel-dir /wheels .

FROM ${PYTHON_IMAGE}
ENV PIP_DISABLE_PIP_VERSION_CHECK=1 \
    PIP_NO_CACHE_DIR=1 \
    PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1
# The wheel's run-time dependencies (pymavlink, fastcrc, numpy, pyyaml, pygeomag) come from PyPI; on
# x86_64 all are prebuilt wheels, so neither stage has a compiler. The wheels are bind-mounted from the
# build stage, never copied into a layer.
RUN --mount=type=bind,from=build,source=/wheels,target=/wheels \
    pip install --no-cache-dir /wheels/*.whl \
    && groupadd --system --gid 10001 mavattitude \
    && useradd --system --uid 10001 --gid 10001 --groups dialout --no-create-home --shell /usr/sbin/nologin mavattitude \
    && mkdir -p /etc/mavattitude
# The config comes from the host: mount a directory holding config.yaml (see configs/*.yaml), read-only.
VOLUME ["/etc/mavattitude"]
# Numeric, so the host can resolve it; a serial link needs `--device /dev/ttyACM0 --group-add dialout`.
USER 10001:10001
WORKDIR /tmp
# The MAVLink link: the config's `link.connect` should be udpin:0.0.0.0:14550 inside a container.
EXPOSE 14550/udp
ENTRYPOINT ["mavattitude"]
CMD ["run", "--config", "/etc/mavattitude/config.yaml"]
