# syntax=docker/dockerfile:1
# quadnav onboard image: the flight daemon (quadnav-onboard) as a non-root user, CPU PyTorch, from
# this one file for linux/amd64 and linux/arm64 (docs/hardware.md, section 9).
#
# Build for this machine:
#   docker build -t quadnav:latest .
# Build for both (BuildKit's buildx; on an x86-64 host the arm64 stages run under QEMU binfmt):
#   docker buildx build --platform linux/amd64,linux/arm64 -t REGISTRY/quadnav:latest --push .
#   docker buildx build --platform linux/arm64 -t quadnav:arm64 --load .
# Motion capture (the quadnav[mocap] extra) is in by default: a wheel on amd64, built from its
# source package in the build stage on arm64 (C++ toolchain, boost, eigen). A vehicle flying on
# PX4's own odometry can leave it out: --build-arg WITH_MOCAP=0.
# Jetson, GPU (JetPack 6 = L4T r36, Ubuntu 22.04, Python 3.10): NVIDIA's JetPack base image and
# NVIDIA's PyTorch wheel for that JetPack instead of CPU torch (docs/hardware.md, section 9):
#   docker buildx build --platform linux/arm64 -t quadnav:jetson \
#     --build-arg BASE_IMAGE=nvcr.io/nvidia/l4t-jetpack:r36.4.0 \
#     --build-arg TORCH_SPEC="torch @ URL-OF-NVIDIA-JETPACK6-TORCH-WHEEL" --build-arg TORCH_INDEX_URL= .
#   docker run --runtime nvidia ... quadnav:jetson
# Smoke test (a sim flight with the bundled model; no hardware):
#   docker run --rm quadnav:latest --dry-run
# Fly (see docs/hardware.md, "Container"): pass the camera and FC devices and the host's quadnav group:
#   docker run --rm --init --network host --device /dev/video2 --device /dev/quadnav/fc-usb \
#     --group-add "$(getent group quadnav | cut -d: -f3)" \
#     -v /etc/quadnav:/etc/quadnav:ro -v /var/lib/quadnav:/var/lib/quadnav quadnav:latest

ARG BASE_IMAGE=python:3.11-slim-bookworm

FROM ${BASE_IMAGE} AS build
# Set by buildx for each platform built (amd64, arm64); only shown in the build log.
ARG TARGETARCH
ARG INSTALL_TORCH=1
ARG TORCH_VERSION=2.13.0
ARG TORCH_SPEC=torch==${TORCH_VERSION}
ARG TORCH_INDEX_URL=https://download.pytorch.org/whl/cpu
ARG WITH_MOCAP=1
ARG VENV_ARGS=
ENV PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    PYTHONDONTWRITEBYTECODE=1
SHELL ["/bin/bash", "-o", "pipefail", "-c"]
# A base without venv (NVIDIA's L4T images) gets it. On arm64 with the mocap extra, what builds
# motioncapture 1.1 from its source package (no arm64 wheel): a C++ compiler, the Boost headers
# (its OptiTrack client is Boost.Asio), Eigen and the Python headers; cmake and ninja come from
# PyPI as its build requirements. Debian/Ubuntu's own package versions: pinning exact revisions
# would break the build each time the archive moves.
# hadolint ignore=DL3008
RUN packages=(); \
    python3 -m venv --help > /dev/null 2>&1 || packages+=(python3-venv python3-pip); \
    if [ "${WITH_MOCAP}" = "1" ] && [ "$(uname -m)" != "x86_64" ]; then \
        packages+=(g++ make libboost-dev libeigen3-dev); \
        [ -f "$(python3 -c 'import sysconfig; print(sysconfig.get_paths()["include"])')/Python.h" ] \
            || packages+=(python3-dev); \
    fi; \
    echo "build stage for ${TARGETARCH:-$(uname -m)}: apt packages: ${packages[*]:-none}"; \
    if [ "${#packages[@]}" -gt 0 ]; then \
        apt-get update \
        && DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends "${packages[@]}" \
        && rm -rf /var/lib/apt/lists/*; \
    fi
# The venv path matches the systemd unit's ExecStart (/opt/quadnav/venv/bin/quadnav-onboard).
RUN python3 -m venv ${VENV_ARGS} /opt/quadnav/venv
ENV PATH=/opt/quadnav/venv/bin:$PATH
# TORCH_SPEC is an exact pin (torch==2.13.0) unless a Jetson build gives NVIDIA's wheel by URL.
# hadolint ignore=DL3013
RUN if [ "${INSTALL_TORCH}" = "1" ]; then \
        pip install ${TORCH_INDEX_URL:+--index-url "${TORCH_INDEX_URL}"} "${TORCH_SPEC}"; \
    fi
WORKDIR /src
COPY pyproject.toml README.md ./
COPY quadnav_onboard ./quadnav_onboard
COPY sim_harness ./sim_harness
COPY scripts/container_health.py /opt/quadnav/bin/container_health.py
# Installs the package and its dependencies (torch is already satisfied), with the mocap extra
# unless WITH_MOCAP=0; then checks that what the daemon imports is there.
RUN if [ "${WITH_MOCAP}" = "1" ]; then extra="[mocap]"; else extra=""; fi \
    && pip install "/src${extra}" \
    && quadnav-onboard --help > /dev/null \
    && python3 -c "import torch, cv2, mavsdk, quadnav_onboard.sdnotify, quadnav_onboard.trigger" \
    && if [ "${WITH_MOCAP}" = "1" ]; then python3 -c "import motioncapture"; fi

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
COPY --from=build /opt/quadnav /opt/quadnav
COPY config/flight.yaml /etc/quadnav/flight.yaml.example
USER 10001:10001
WORKDIR /var/lib/quadnav
# Healthy = the daemon's own sd_notify state, as systemd's Type=notify + WatchdogSec=10s read it:
# READY=1 sent (preflight passed), no STOPPING=1, a notification within the last 10 s. The entry
# point (container_health.py run) plays systemd's notify socket; the check only reads its state
# file. The start period covers preflight (the unit's TimeoutStartSec=120).
HEALTHCHECK --interval=10s --timeout=5s --start-period=120s --start-interval=5s --retries=3 \
    CMD ["/opt/quadnav/venv/bin/python3", "/opt/quadnav/bin/container_health.py", "check"]
ENTRYPOINT ["/opt/quadnav/venv/bin/python3", "/opt/quadnav/bin/container_health.py", "run", "--", "quadnav-onboard"]
CMD ["--config", "/etc/quadnav/flight.yaml"]
