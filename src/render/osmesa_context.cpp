// OSMesa backend of the context layer. This is the only file that includes an OSMesa or
// GL header with prototypes, and it calls OSMesa* functions only: every gl* function is
// fetched through OSMesaGetProcAddress (see context.h for why).

#include <GL/osmesa.h>

#include <string>
#include <vector>

#include "zsculpt/core/errors.h"
#include "zsculpt/render/context.h"

namespace zsculpt::render {

struct OsMesaContext::Impl {
  OSMesaContext context = nullptr;
  // OSMesa renders the default framebuffer into client memory; the renderer draws into its
  // own framebuffer objects, so this buffer stays small.
  std::vector<unsigned char> buffer;
};

OsMesaContext::OsMesaContext(int width, int height)
    : impl_(std::make_unique<Impl>()), width_(width), height_(height) {
  if (width < 1 || height < 1) {
    throw InvalidInputError("OSMesa: context size must be at least 1 x 1");
  }
  const int attributes[] = {OSMESA_FORMAT,
                            OSMESA_RGBA,
                            OSMESA_DEPTH_BITS,
                            24,
                            OSMESA_STENCIL_BITS,
                            0,
                            OSMESA_ACCUM_BITS,
                            0,
                            OSMESA_PROFILE,
                            OSMESA_CORE_PROFILE,
                            OSMESA_CONTEXT_MAJOR_VERSION,
                            3,
                            OSMESA_CONTEXT_MINOR_VERSION,
                            3,
                            0};
  impl_->context = OSMesaCreateContextAttribs(attributes, nullptr);
  if (impl_->context == nullptr) {
    throw IOError(
        "OSMesa: cannot create an OpenGL 3.3 core context (is Mesa's libOSMesa "
        "with llvmpipe installed?)");
  }
  impl_->buffer.assign(static_cast<size_t>(width) * height * 4, 0);
  makeCurrent();
}

OsMesaContext::~OsMesaContext() {
  if (impl_ && impl_->context != nullptr) OSMesaDestroyContext(impl_->context);
}

void OsMesaContext::makeCurrent() {
  if (OSMesaMakeCurrent(impl_->context, impl_->buffer.data(), GL_UNSIGNED_BYTE, width_, height_) ==
      0) {
    throw IOError("OSMesa: cannot make the context current");
  }
}

GlProc OsMesaContext::getProcAddress(const char* name) const {
  return reinterpret_cast<GlProc>(OSMesaGetProcAddress(name));
}

}  // namespace zsculpt::render
