# One image for every service of the system (sim, agents, adapter, recorder, human gateway, router,
# sweep workers): the `tsf` command on Python 3.11, built from this checkout, nothing downloaded but
# the pinned Python packages (and not even those with OFFLINE=1, see docker/wheelhouse).
# BASE: any Debian-like image with python3 (3.11) and its venv module. Without a registry,
# docker/base-image builds one with debootstrap.
ARG BASE=python:3.11-slim-bookworm

FROM ${BASE} AS build
# OFFLINE=1: install only from the wheelhouse docker/wheels (filled on the host by docker/wheelhouse).
ARG OFFLINE=
ENV PIP_DISABLE_PIP_VERSION_CHECK=1 PIP_NO_CACHE_DIR=1 PIP_FIND_LINKS=/tmp/wheels
WORKDIR /app
COPY docker/wheels/ /tmp/wheels/
COPY pyproject.toml requirements.lock README.md ./
# The dependencies first, at the lock's versions, in their own layer: code changes do not reinstall them.
RUN python3 -m venv /opt/venv \
    && python3 -c "import tomllib; print(*tomllib.load(open('pyproject.toml', 'rb'))['project']['dependencies'], sep='\n')" \
        >/tmp/requirements.txt \
    && /opt/venv/bin/pip install ${OFFLINE:+--no-index} -r /tmp/requirements.txt -c requirements.lock
COPY services/ services/
COPY shared/ shared/
# Editable: the policy library's weights and table are read from the source tree.
RUN /opt/venv/bin/pip install ${OFFLINE:+--no-index} --no-deps -e . \
    && find /app -name __pycache__ -prune -exec rm -rf {} +

FROM ${BASE}
COPY --from=build /opt/venv /opt/venv
COPY --from=build /app /app
ENV PATH=/opt/venv/bin:$PATH PYTHONUNBUFFERED=1
RUN useradd --uid 10001 --create-home tsf && mkdir /recordings && chown tsf /recordings
USER tsf
WORKDIR /app
EXPOSE 7447
CMD ["tsf", "--help"]
