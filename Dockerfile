# One image for the api, worker and beat services of docker-compose.yml.
FROM python:3.11-slim-bookworm

RUN apt-get update \
    && apt-get install -y --no-install-recommends libusb-1.0-0 libgl1 libegl1 libgomp1 \
        fonts-ipaexfont-gothic \
    && rm -rf /var/lib/apt/lists/*

WORKDIR /app
COPY requirements.lock ./
# The lock pins the CPU build of torch (2.13.0+cpu); the registry's 2.13.0 is the same
# release. Pass --build-arg PIP_EXTRA_INDEX_URL=... to take the CPU build from its index.
ARG PIP_EXTRA_INDEX_URL=""
RUN if [ -z "$PIP_EXTRA_INDEX_URL" ]; then sed -i 's/^torch==2.13.0+cpu$/torch==2.13.0/' requirements.lock; fi \
    && pip install --no-cache-dir -r requirements.lock

COPY . .
RUN pip install --no-cache-dir --no-deps -e .

ENV SLIDEWATCH_DATA_DIR=/data
VOLUME ["/data"]
EXPOSE 8000
CMD ["slidewatch", "api", "--host", "0.0.0.0"]
