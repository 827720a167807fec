# shadowmap-service: the renderer library, the `shadowmap` CLI and the HTTP service,
# rendering offscreen with Mesa's llvmpipe through EGL (default) or OSMesa.
#
#   docker build -t shadowmap-service .                          # the runtime stage (default)
#   docker run --init -p 8000:8000 shadowmap-service
#   docker build --target test -t shadowmap-service:test .      # runtime + test tools + tests/
#   docker run --rm --init -v /path/to/models:/opt/shared/models:ro shadowmap-service:test
#
# Stages: base (Python, Mesa, the user, an empty virtualenv); wheel (builds the project's wheel,
# nothing else of it is kept); deps (base + the pinned dependencies of requirements/runtime.lock);
# runtime (deps + the wheel: no test tools, no tests); test (deps + requirements/test.lock + the
# wheel + tests/). The locks are made from pyproject.toml by scripts/lock.
#
# The base is an argument so that a machine without access to a registry can
# build on a locally made Debian bookworm image (see scripts/container-test).
ARG BASE=debian:bookworm-slim
FROM ${BASE} AS base

ENV DEBIAN_FRONTEND=noninteractive \
    LANG=C.UTF-8 \
    PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1

# Python, and Mesa: EGL and OSMesa on llvmpipe, plus libGL and libXrender, which
# pyrender's viewer module loads on import even when rendering offscreen.
RUN apt-get update -qq \
 && apt-get install -y -qq --no-install-recommends \
        ca-certificates \
        python3 python3-venv \
        libegl1 libegl-mesa0 libgl1-mesa-dri libosmesa6 libgl1 libxrender1 \
        >/dev/null \
 && rm -rf /var/lib/apt/lists/*

# The user the service and the tests run as.
RUN useradd --uid 10001 --user-group --create-home --home-dir /home/app --shell /usr/sbin/nologin app

# The virtualenv, without the setuptools that Python 3.11 seeds it with: nothing at run time
# uses it, and wheels need none to install.
RUN python3 -m venv /opt/venv \
 && /opt/venv/bin/python -m pip uninstall -q -y setuptools
ENV VIRTUAL_ENV=/opt/venv \
    PATH=/opt/venv/bin:/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin

# ---------------------------------------------------------------------------------------------
# The project as a wheel (pip builds it with the setuptools that pyproject.toml names); only
# the wheel leaves this stage. Only what the wheel is made of is copied, so a change to the
# tests does not rebuild it, and SOURCE_DATE_EPOCH fixes the timestamps inside it, so that an
# unchanged source gives the same wheel and the layers that install it stay cached. (A new
# top-level folder in pyproject.toml's package-dir needs its COPY line here.)
FROM base AS wheel
COPY pyproject.toml README.md LICENSE /tmp/src/
COPY shadowmap /tmp/src/shadowmap
COPY renderer /tmp/src/renderer
COPY app /tmp/src/app
COPY shaders /tmp/src/shaders
RUN SOURCE_DATE_EPOCH=315532800 pip wheel -q --no-deps --wheel-dir /tmp/wheel /tmp/src

# ---------------------------------------------------------------------------------------------
# The service's third-party dependencies, every one pinned with its hashes
# (requirements/runtime.lock). --no-deps: the lock is complete, so nothing unpinned can come
# in; `pip check` in the stages below confirms that it satisfies the project.
FROM base AS deps
COPY requirements/runtime.lock /tmp/deps/runtime.lock
RUN pip install -q --require-hashes --no-deps --only-binary=:all: -r /tmp/deps/runtime.lock \
 && rm -rf /tmp/deps

# ---------------------------------------------------------------------------------------------
# runtime: what the service needs and nothing else.
FROM deps AS runtime

# The project itself: a regular (non-editable) install, so the shaders and the app's static
# files are loaded from site-packages.
COPY --from=wheel /tmp/wheel /tmp/wheel
RUN pip install -q --no-deps /tmp/wheel/*.whl \
 && rm -rf /tmp/wheel \
 && pip check

USER app
WORKDIR /home/app

ENV PYOPENGL_PLATFORM=egl
EXPOSE 8000

HEALTHCHECK --interval=30s --timeout=5s --start-period=30s --retries=3 \
    CMD ["python", "-c", "import sys, urllib.request; sys.exit(0 if urllib.request.urlopen('http://127.0.0.1:8000/healthz', timeout=4).status == 200 else 1)"]

CMD ["shadowmap", "serve", "--host", "0.0.0.0", "--port", "8000"]

# ---------------------------------------------------------------------------------------------
# test: the runtime stage's layers (the same pinned dependencies, the same wheel) with the test
# tools of requirements/test.lock (the same pins plus the `test` extra) installed between the
# dependencies and the wheel, so that a code change does not download them again, and the
# tests, run against the installed package (no source packages beside them):
#   docker run --rm --init -v /path/to/models:/opt/shared/models:ro shadowmap-service:test
# The tests look for models in ../shared/models from /opt/shadowmap, or in $SHADOWMAP_MODELS.
FROM deps AS test
COPY requirements/test.lock /tmp/deps/test.lock
RUN pip install -q --require-hashes --no-deps --only-binary=:all: -r /tmp/deps/test.lock \
 && rm -rf /tmp/deps

COPY --from=wheel /tmp/wheel /tmp/wheel
RUN pip install -q --no-deps /tmp/wheel/*.whl \
 && rm -rf /tmp/wheel \
 && pip check

# Owned by the runtime user, so tests may write beside themselves.
RUN install -d -o app -g app /opt/shadowmap
COPY --chown=app:app pyproject.toml /opt/shadowmap/pyproject.toml
COPY --chown=app:app tests /opt/shadowmap/tests

USER app
WORKDIR /opt/shadowmap
ENV PYOPENGL_PLATFORM=egl
CMD ["python", "-m", "pytest", "-q", "-p", "no:cacheprovider"]

# ---------------------------------------------------------------------------------------------
# The default target of a plain `docker build .`: the runtime stage.
FROM runtime
