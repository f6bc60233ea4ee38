# neural-shdf REST service: the README's `pip install .` at the versions locked in constraints.txt
# (the same set the tests run with), as a non-root user.

# three.js for the web viewer, from npm at the version locked in the viewer's package-lock.json;
# the service serves this copy (NEURAL_SHDF_VIEWER_THREE_DIR below), so the image needs no CDN.
FROM node:20-slim AS viewer
WORKDIR /viewer
COPY service/neural_shdf/viewer/package.json service/neural_shdf/viewer/package-lock.json ./
RUN npm ci --no-audit --no-fund --loglevel=error

FROM python:3.11-slim

ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1

RUN useradd --create-home --uid 10001 --shell /usr/sbin/nologin neural-shdf

WORKDIR /src
COPY pyproject.toml README.md constraints.txt ./
COPY service ./service
# The committed ONNX model (service/neural_shdf/models/emd.onnx) is package data: installed here.
RUN pip install -c constraints.txt . && rm -rf /src

COPY --from=viewer /viewer/node_modules/three /opt/three
ENV NEURAL_SHDF_VIEWER_THREE_DIR=/opt/three

USER neural-shdf
WORKDIR /home/neural-shdf
ENV NEURAL_SHDF_HOST=0.0.0.0 \
    NEURAL_SHDF_PORT=8000 \
    NEURAL_SHDF_CACHE_DIR=/home/neural-shdf/.cache/neural-shdf/service \
    NUMBA_CACHE_DIR=/home/neural-shdf/.cache/numba
RUN mkdir -p "$NEURAL_SHDF_CACHE_DIR"
# Compile the numba kernels once into the image (a fresh install spends ~15 s on them);
# the service still runs the same warm-up at start-up, then from this cache in ~1 s.
RUN python -c "from neural_shdf.pipeline import warm_up; print(f'warm-up {warm_up():.1f} s')"
VOLUME ["/home/neural-shdf/.cache/neural-shdf"]
EXPOSE 8000

HEALTHCHECK --interval=30s --timeout=5s --start-period=30s --retries=3 \
    CMD ["python", "-c", "import os, urllib.request; urllib.request.urlopen('http://127.0.0.1:%s/healthz' % os.environ.get('NEURAL_SHDF_PORT', '8000'), timeout=4)"]

CMD ["neural-shdf", "serve"]
