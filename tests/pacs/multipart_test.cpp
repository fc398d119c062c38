// multipart/related parsing (pacs/multipart.h) on bodies written by hand from RFC 2046's
// grammar: what WADO-RS servers send, and the damaged bodies a dropped connection leaves.
#include <gtest/gtest.h>

#include <string>

#include "octoray/core/error.h"
#include "octoray/pacs/credentials.h"
#include "octoray/pacs/dicomweb.h"
#include "octoray/pacs/multipart.h"

namespace {

using namespace octoray;
using namespace octoray::pacs;

const std::string kBody =
    "preamble to ignore\r\n"
    "--XyZ\r\n"
    "Content-Type: application/dicom\r\n"
    "Content-Location: a\r\n"
    "\r\n"
    "first\r\n--not the boundary\r\n"
    "\r\n--XyZ  \r\n"
    "content-type: application/dicom\r\n"
    "\r\n"
    "second"
    "\r\n--XyZ--\r\n"
    "epilogue";

TEST(Multipart, BoundaryFromQuotedAndBareParameters) {
  EXPECT_EQ(multipartBoundary("multipart/related; type=\"application/dicom\"; boundary=XyZ", "u"), "XyZ");
  EXPECT_EQ(multipartBoundary("Multipart/Related;boundary=\"a b;c\";type=x", "u"), "a b;c");
  EXPECT_THROW(multipartBoundary("application/dicom+json", "u"), Error);
  EXPECT_THROW(multipartBoundary("multipart/related; type=\"application/dicom\"", "u"), Error);
  EXPECT_THROW(multipartBoundary("multipart/related; boundary=\"\"", "u"), Error);
}

TEST(Multipart, PartsWithHeadersPaddingPreambleAndEpilogue) {
  const auto parts = parseMultipart(kBody, "XyZ", "u");
  ASSERT_EQ(parts.size(), 2u);
  EXPECT_EQ(parts[0].contentType, "application/dicom");
  EXPECT_EQ(parts[0].body, "first\r\n--not the boundary\r\n");
  EXPECT_EQ(parts[1].contentType, "application/dicom");
  EXPECT_EQ(parts[1].body, "second");
}

TEST(Multipart, BinaryBodiesKeepEveryByte) {
  std::string payload(1000, '\0');
  for (std::size_t i = 0; i < payload.size(); ++i) payload[i] = static_cast<char>(i * 37);
  const std::string body = "--b\r\n\r\n" + payload + "\r\n--b--";
  const auto parts = parseMultipart(body, "b", "u");
  ASSERT_EQ(parts.size(), 1u);
  EXPECT_EQ(parts[0].body, payload);
  EXPECT_TRUE(parts[0].contentType.empty());
}

// Every prefix of a valid body (a connection dropped anywhere) is an error, never fewer parts.
TEST(Multipart, EveryTruncationIsAnError) {
  const std::string full = kBody.substr(0, kBody.find("--XyZ--") + 7);
  for (std::size_t n = 0; n < full.size(); ++n) {
    SCOPED_TRACE(n);
    EXPECT_THROW(parseMultipart(std::string_view(full).substr(0, n), "XyZ", "u"), Error);
  }
  EXPECT_NO_THROW(parseMultipart(full, "XyZ", "u"));
}

TEST(Multipart, MalformedBodiesNameTheProblem) {
  try {
    parseMultipart("no delimiter at all", "XyZ", "https://pacs/x");
    FAIL() << "no error";
  } catch (const Error& e) {
    EXPECT_EQ(e.path(), "https://pacs/x");
    EXPECT_NE(std::string(e.what()).find("malformed multipart body"), std::string::npos) << e.what();
  }
  EXPECT_THROW(parseMultipart("--XyZjunk\r\n\r\nx\r\n--XyZ--", "XyZ", "u"), Error);
  EXPECT_THROW(parseMultipart("--XyZ\r\nContent-Type: a\r\nbody without blank line\r\n--XyZ--", "XyZ", "u"), Error);
}

TEST(Credentials, ParsedFromOneLineNeverQuotedInErrors) {
  const Credentials basic = parseCredentials("# comment\n\nbasic reader:p@ss:word\n", "f");
  EXPECT_EQ(basic.kind, Credentials::Kind::Basic);
  EXPECT_EQ(basic.user, "reader");
  EXPECT_EQ(basic.secret, "p@ss:word");
  const Credentials bearer = parseCredentials("bearer abc.def-ghi", "f");
  EXPECT_EQ(bearer.kind, Credentials::Kind::Bearer);
  EXPECT_EQ(bearer.secret, "abc.def-ghi");
  for (const char* bad : {"", "# only a comment", "basic nocolon-s3cretpw", "bearer two s3cretpw",
                          "token s3cretpw", "basic a:s3cretpw\nbearer s3cretpw"}) {
    SCOPED_TRACE(bad);
    try {
      parseCredentials(bad, "creds.txt");
      FAIL() << "accepted";
    } catch (const Error& e) {
      EXPECT_EQ(e.path(), "creds.txt");
      EXPECT_EQ(std::string(e.what()).find("s3cretpw"), std::string::npos) << e.what();
    }
  }
}

TEST(Credentials, UrlsWithUserInformationAreRefusedWithoutRepeatingThem) {
  for (const char* url : {"https://reader:s3cretpw@pacs.example/dicom-web", "http://s3cretpw@h/x"}) {
    try {
      refuseCredentialsInUrl(url);
      FAIL() << "accepted";
    } catch (const Error& e) {
      EXPECT_EQ(std::string(e.what()).find("s3cretpw"), std::string::npos) << e.what();
    }
    EXPECT_THROW(DicomWebClient(url, {}), Error);
  }
  EXPECT_NO_THROW(refuseCredentialsInUrl("https://pacs.example/dicom-web?x=a@b"));
}

TEST(DicomWebUrl, SplitsServiceRootStudyAndSeries) {
  const auto t = parseDicomWebUrl("https://pacs.example:8443/dicom-web/studies/1.2.3/series/4.5.6/");
  EXPECT_EQ(t.baseUrl, "https://pacs.example:8443/dicom-web");
  EXPECT_EQ(t.studyUid, "1.2.3");
  EXPECT_EQ(t.seriesUid, "4.5.6");
  const auto root = parseDicomWebUrl("http://h/wado");
  EXPECT_EQ(root.baseUrl, "http://h/wado");
  EXPECT_TRUE(root.studyUid.empty());
  EXPECT_THROW(parseDicomWebUrl("http://h/dicom-web/studies/1.2.3/series/../../x"), Error);
  EXPECT_THROW(parseDicomWebUrl("ftp://h/dicom-web"), Error);
}

}  // namespace
