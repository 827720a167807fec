# shadowmap-service: the renderer library, the `shadowmap` CLI and the HTTP service,
# rendering offscreen with Mesa's llvmpipe through EGL (default) or OSMesa.
#
#   docker build -t shadowmap-service .
#   docker run --init -p 8000:8000 shadowmap-service
#
# The base is an argument so that a machine without access to a registry can
# build on a locally made Debian bookworm image (see scripts/container-test).
ARG BASE=debian:bookworm-slim
FROM ${BASE}

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

RUN python3 -m venv /opt/venv
ENV VIRTUAL_ENV=/opt/venv \
    PATH=/opt/venv/bin:/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin

# Third-party dependencies first, read from pyproject.toml alone, so that this
# (slow) layer is reused while only the project's own code changes.
COPY pyproject.toml /tmp/deps/pyproject.toml
RUN python -c "import tomllib; p = tomllib.load(open('/tmp/deps/pyproject.toml', 'rb'))['project']; extras = p.get('optional-dependencies', {}); deps = list(p.get('dependencies', [])) + [d for e in ('server', 'test') for d in extras.get(e, [])]; print('\n'.join(d for d in deps if not d.replace('_', '-').lower().startswith(p['name'].lower())))" > /tmp/deps/requirements.txt \
 && pip install -q -r /tmp/deps/requirements.txt \
 && rm -rf /tmp/deps

# The project itself: a regular (non-editable) install, so the shaders and the
# app's static files are loaded from site-packages.
COPY . /tmp/src
RUN pip install -q "/tmp/src[server,test]" \
 && rm -rf /tmp/src

# The tests and the pytest configuration, to run the suite against the installed
# package (no source packages beside them):
#   docker run --rm --init -v /path/to/models:/opt/shared/models:ro \
#       -w /opt/shadowmap shadowmap-service python -m pytest -q
# The tests look for models in ../shared/models from /opt/shadowmap, or in $SHADOWMAP_MODELS.
# Owned by the runtime user, so tests may write beside themselves.
RUN install -d -o app -g app /opt/shadowmap
COPY --chown=app:app pyproject.toml /opt/shadowmap/pyproject.toml
COPY --chown=app:app tests /opt/shadowmap/tests

USER app
WORKDIR /home/app

ENV PYOPENGL_PLATFORM=egl
EXPOSE 8000

HEALTHCHECK --interval=30s --timeout=5s --start-period=30s --retries=3 \
    CMD ["python", "-c", "import sys, urllib.request; sys.exit(0 if urllib.request.urlopen('http://127.0.0.1:8000/healthz', timeout=4).status == 200 else 1)"]

CMD ["shadowmap", "serve", "--host", "0.0.0.0", "--port", "8000"]
