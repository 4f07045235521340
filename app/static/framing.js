// Binary socket messages (workers/streaming/framing.py): a 4-byte big-endian header length, a JSON header, then the
// payload: a rendered frame's JPEG, or a live frame set's JPEGs one after another (their sizes in the header).

/** The header (an object) and payload (Uint8Array over ``buffer``) of binary message ``buffer`` (ArrayBuffer). */
export function unpackMessage(buffer) {
  const length = new DataView(buffer).getUint32(0);
  const header = JSON.parse(new TextDecoder().decode(new Uint8Array(buffer, 4, length)));
  return { header, payload: new Uint8Array(buffer, 4 + length) };
}

/** ``payload`` cut into parts of ``sizes`` bytes, in order (Uint8Arrays over the same buffer). */
export function splitPayload(payload, sizes) {
  let offset = 0;
  return sizes.map((size) => {
    const part = payload.subarray(offset, offset + size);
    offset += size;
    return part;
  });
}
