"""Where everything lives in the platform's file storage: one function per folder or file.

Paths are relative to the storage root (`LocalStorage.absolute` makes them absolute) and
use "/" on every system, as they are kept in the database (StoredFile.path). The layout:

    surveys/{site_id}/                          site_surveys_folder: uploaded DSMs and
        {random}.tif, {random}.cog.tif          their COGs (services/surveys.py)
        {survey_id}/                            survey_folder: a video or photo survey
            files/                              survey_files_folder: its video, flight
                                                log and photos (services/survey_sources.py)
            reconstruction/                     survey_reconstruction_folder: the work
                                                folder of its reconstruction job, whose
                                                outputs are its products
    comparisons/{comparison_id}/                comparison_folder: work files and products
        {file}                                  comparison_file
        cog/{file}                              comparison_cog_file: COGs of its rasters
    uploads/{site_id}/                          site_uploads_folder: resumable uploads
        {upload_id}.part                        upload_part_file: bytes until complete
    reports/{site_id}/{report_id}/              report_folder: report.pdf, report.html,
        {file}                                  map.png (report_file)
    datasets/                                   DATASETS_FOLDER: training dataset
                                                manifests, put there by an operator
    models/{name}/{run}/                        model_run_folder: one training run, its
        {file}                                  checkpoints, weights and model card
                                                (model_run_file)

Deleting a site removes its comparison and survey folders and its uploads folder
(services/deletion.py); files recorded as StoredFile rows are removed one by one.
"""

SURVEYS_FOLDER = "surveys"
COMPARISONS_FOLDER = "comparisons"
UPLOADS_FOLDER = "uploads"
REPORTS_FOLDER = "reports"
DATASETS_FOLDER = "datasets"
MODELS_FOLDER = "models"
SURVEY_FILES = "files"
RECONSTRUCTION = "reconstruction"
COG = "cog"


def _join(*parts: str | int) -> str:
    return "/".join(str(part) for part in parts)


def site_surveys_folder(site_id: int) -> str:
    """Surveys of a site: uploaded DSMs and their COGs, and one folder per source survey."""
    return _join(SURVEYS_FOLDER, site_id)


def survey_folder(site_id: int, survey_id: int) -> str:
    """A source survey's uploaded files and reconstruction."""
    return _join(site_surveys_folder(site_id), survey_id)


def survey_files_folder(site_id: int, survey_id: int) -> str:
    """A source survey's video, flight log and photos, as uploaded."""
    return _join(survey_folder(site_id, survey_id), SURVEY_FILES)


def survey_reconstruction_folder(site_id: int, survey_id: int) -> str:
    """The work folder of a survey's reconstruction job; its outputs become products."""
    return _join(survey_folder(site_id, survey_id), RECONSTRUCTION)


def survey_reconstruction_file(site_id: int, survey_id: int, name: str) -> str:
    return _join(survey_reconstruction_folder(site_id, survey_id), name)


def comparison_folder(comparison_id: int) -> str:
    """A comparison's work files and products (comparisons are named by id alone)."""
    return _join(COMPARISONS_FOLDER, comparison_id)


def comparison_file(comparison_id: int, name: str) -> str:
    return _join(comparison_folder(comparison_id), name)


def comparison_cog_folder(comparison_id: int) -> str:
    """Cloud-Optimized GeoTIFFs made from a comparison's rasters, named as their source."""
    return _join(comparison_folder(comparison_id), COG)


def comparison_cog_file(comparison_id: int, name: str) -> str:
    return _join(comparison_cog_folder(comparison_id), name)


def site_uploads_folder(site_id: int) -> str:
    """A site's unfinished resumable uploads."""
    return _join(UPLOADS_FOLDER, site_id)


def upload_part_file(site_id: int, upload_id: int) -> str:
    """The bytes of a resumable upload received so far (moved away when it completes)."""
    return _join(site_uploads_folder(site_id), f"{upload_id}.part")


def report_folder(site_id: int, report_id: int) -> str:
    """A report's files, as worker/reports writes them."""
    return _join(REPORTS_FOLDER, site_id, report_id)


def report_file(site_id: int, report_id: int, name: str) -> str:
    return _join(report_folder(site_id, report_id), name)


def model_run_folder(name: str, run: str) -> str:
    """One training run of the model `name`; the trained weights stay there."""
    return _join(MODELS_FOLDER, name, run)


def model_run_file(name: str, run: str, file_name: str) -> str:
    return _join(model_run_folder(name, run), file_name)
