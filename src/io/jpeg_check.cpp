// Decodes a JPEG with libjpeg to find damaged entropy data. OpenCV decodes a JPEG whose data is
// corrupt (a flipped byte, a cut-off file re-terminated with an end-of-image marker) into an image
// that is partly garbage or grey, with only libjpeg's warning on stderr; here those warnings are
// errors. The decode is at 1/8 scale: the entropy data is read in full (that is where damage shows),
// the inverse DCT and upsampling are mostly skipped.
#include <csetjmp>
#include <cstddef>
#include <cstdio>

// jpeglib.h needs size_t and FILE declared first; jerror.h needs the version jpeglib.h defines.
#include <jpeglib.h>

#include <jerror.h>

#include "image_header.h"
#include "nerfslam/core/error.h"

namespace nerfslam::io_detail {
namespace {

struct ErrorManager {
  jpeg_error_mgr pub;
  std::jmp_buf jump;
  char message[JMSG_LENGTH_MAX];
  bool corrupt;
};

// libjpeg's warnings that mean the pixels decoded are not the image's (its "Corrupt JPEG data"
// family and a premature end). The others (an unknown JFIF revision, an Adobe transform code, a bad
// ICC marker) leave the pixels as they are.
bool damagesPixels(int code) {
  switch (code) {
    case JWRN_ARITH_BAD_CODE:
    case JWRN_BOGUS_PROGRESSION:
    case JWRN_EXTRANEOUS_DATA:
    case JWRN_HIT_MARKER:
    case JWRN_HUFF_BAD_CODE:
    case JWRN_JPEG_EOF:
    case JWRN_MUST_RESYNC:
      return true;
    default:
      return false;
  }
}

[[noreturn]] void onError(j_common_ptr c) {
  auto* e = reinterpret_cast<ErrorManager*>(c->err);
  c->err->format_message(c, e->message);
  std::longjmp(e->jump, 1);
}

void onMessage(j_common_ptr c, int level) {
  if (level != -1 || !damagesPixels(c->err->msg_code)) return;  // trace output, harmless warnings
  auto* e = reinterpret_cast<ErrorManager*>(c->err);
  c->err->format_message(c, e->message);
  e->corrupt = true;
  std::longjmp(e->jump, 1);
}

}  // namespace

void checkJpegData(const std::vector<uint8_t>& b, const std::string& path) {
  jpeg_decompress_struct cinfo;
  ErrorManager err;
  err.message[0] = '\0';
  err.corrupt = false;
  cinfo.err = jpeg_std_error(&err.pub);
  err.pub.error_exit = onError;
  err.pub.emit_message = onMessage;
  jpeg_create_decompress(&cinfo);
  // No C++ object with a destructor lives between here and the longjmps (libjpeg's own memory is
  // freed by jpeg_destroy_decompress).
  if (setjmp(err.jump)) {
    jpeg_destroy_decompress(&cinfo);
    if (err.corrupt) fail("{}: corrupt JPEG image: {}", path, err.message);
    fail("{}: not a readable JPEG image: {}", path, err.message);
  }
  jpeg_mem_src(&cinfo, b.data(), static_cast<unsigned long>(b.size()));
  jpeg_read_header(&cinfo, TRUE);
  cinfo.scale_num = 1;
  cinfo.scale_denom = 8;
  cinfo.dct_method = JDCT_IFAST;
  cinfo.do_fancy_upsampling = FALSE;
  cinfo.do_block_smoothing = FALSE;
  jpeg_start_decompress(&cinfo);
  JSAMPARRAY row = (*cinfo.mem->alloc_sarray)(reinterpret_cast<j_common_ptr>(&cinfo), JPOOL_IMAGE,
                                              cinfo.output_width * static_cast<JDIMENSION>(cinfo.output_components), 1);
  while (cinfo.output_scanline < cinfo.output_height) jpeg_read_scanlines(&cinfo, row, 1);
  jpeg_finish_decompress(&cinfo);
  jpeg_destroy_decompress(&cinfo);
}

}  // namespace nerfslam::io_detail
