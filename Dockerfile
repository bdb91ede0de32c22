# One image for the api, the workers and the annotator (docker-compose.yml). CPU PyTorch; CUDA wheels can replace it.
FROM python:3.11-slim

ENV PYTHONDONTWRITEBYTECODE=1 PYTHONUNBUFFERED=1 PIP_NO_CACHE_DIR=1 \
    TRACKLABEL_DATA_DIR=/data TRACKLABEL_DATA_ROOTS=/datasets
RUN apt-get update && apt-get install -y --no-install-recommends libgl1 libglib2.0-0 \
    && rm -rf /var/lib/apt/lists/*
WORKDIR /srv/tracklabel

# torch first (pinned as in the Makefile), then the package with the PostgreSQL driver, every
# package at the version of constraints.txt
COPY constraints.txt ./
RUN pip install -c constraints.txt "torch==2.13.0"
COPY pyproject.toml README.md ./
COPY pipeline ./pipeline
COPY app ./app
COPY annotator_ui ./annotator_ui
COPY research ./research
COPY migrations ./migrations
COPY alembic.ini ./
RUN pip install -c constraints.txt ".[postgres]" && useradd --create-home tracklabel && mkdir -p /data /datasets \
    && chown tracklabel /data
USER tracklabel

EXPOSE 8000 8080
HEALTHCHECK --interval=15s --timeout=5s --retries=5 CMD \
    python -c "import urllib.request,sys; sys.exit(urllib.request.urlopen('http://127.0.0.1:8000/api/v1/health').status != 200)"
CMD ["tracklabel", "serve", "--host", "0.0.0.0", "--port", "8000"]
