# syntax=docker/dockerfile:1
# quadnav onboard image: the flight daemon (quadnav-onboard) as a non-root user, CPU PyTorch.
#
# Build (x86-64 or generic ARM64, CPU torch from the PyTorch CPU index):
#   docker build -t quadnav:latest .
#   docker buildx build --platform linux/arm64 -t quadnav:arm64 .
# Build on a Jetson (JetPack 6; the base already has CUDA PyTorch, so do not install torch again):
#   docker build -t quadnav:jetson \
#     --build-arg BASE_IMAGE=dustynv/l4t-pytorch:r36.2.0 \
#     --build-arg INSTALL_TORCH=0 --build-arg VENV_ARGS=--system-site-packages .
# Smoke test (a sim flight with the bundled model; no hardware):
#   docker run --rm quadnav:latest --dry-run
# Fly (see docs/hardware.md, "Container"): pass the camera and FC devices and the host's quadnav group:
#   docker run --rm --network host --device /dev/video2 --device /dev/quadnav/fc-usb \
#     --group-add "$(getent group quadnav | cut -d: -f3)" \
#     -v /etc/quadnav:/etc/quadnav:ro -v /var/lib/quadnav:/var/lib/quadnav quadnav:latest

ARG BASE_IMAGE=python:3.11-slim-bookworm

FROM ${BASE_IMAGE} AS build
ARG INSTALL_TORCH=1
ARG TORCH_VERSION=2.13.0
ARG TORCH_INDEX_URL=https://download.pytorch.org/whl/cpu
ARG VENV_ARGS=
ENV PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    PYTHONDONTWRITEBYTECODE=1
SHELL ["/bin/bash", "-o", "pipefail", "-c"]
# The venv path matches the systemd unit's ExecStart (/opt/quadnav/venv/bin/quadnav-onboard).
RUN python3 -m venv ${VENV_ARGS} /opt/quadnav/venv
ENV PATH=/opt/quadnav/venv/bin:$PATH
RUN if [ "${INSTALL_TORCH}" = "1" ]; then \
        pip install --index-url "${TORCH_INDEX_URL}" "torch==${TORCH_VERSION}"; \
    fi
WORKDIR /src
COPY pyproject.toml README.md ./
COPY quadnav_onboard ./quadnav_onboard
COPY sim_harness ./sim_harness
# Installs the package and its pinned-by-pyproject dependencies; torch is already satisfied.
RUN pip install /src \
    && quadnav-onboard --help > /dev/null \
    && python3 -c "import torch, cv2, mavsdk, quadnav_onboard.sdnotify, quadnav_onboard.trigger"

FROM ${BASE_IMAGE} AS runtime
ENV PATH=/opt/quadnav/venv/bin:$PATH \
    PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    OMP_NUM_THREADS=2 \
    NUMBA_CACHE_DIR=/var/lib/quadnav/numba-cache
# A fixed, unprivileged uid/gid; on the host, pass the device group with --group-add.
RUN groupadd --system --gid 10001 quadnav \
    && useradd --system --uid 10001 --gid quadnav --home-dir /var/lib/quadnav --shell /usr/sbin/nologin quadnav \
    && install -d -o quadnav -g quadnav -m 0750 /var/lib/quadnav /run/quadnav \
    && install -d -o root -g quadnav -m 0750 /etc/quadnav
COPY --from=build /opt/quadnav/venv /opt/quadnav/venv
COPY config/flight.yaml /etc/quadnav/flight.yaml.example
USER 10001:10001
WORKDIR /var/lib/quadnav
# The health check is the dry run (a complete sim flight with the bundled model, at the lowest CPU
# priority): run early after start, then daily. For a real flight prefer systemd (Type=notify +
# WatchdogSec) or `docker run --no-healthcheck`, so that no sim competes with the planner.
HEALTHCHECK --interval=24h --timeout=5m --start-period=10m --start-interval=30s --retries=1 \
    CMD ["nice", "-n", "19", "quadnav-onboard", "--dry-run"]
ENTRYPOINT ["quadnav-onboard"]
CMD ["--config", "/etc/quadnav/flight.yaml"]
